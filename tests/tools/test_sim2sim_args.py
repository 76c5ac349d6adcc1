"""sim2sim reads its arg file as `mimickit test` does (its Newton side is tested in tests/engines)."""

from __future__ import annotations

from pathlib import Path

import pytest

from mimickit.tools.sim2sim import run_sim2sim
from mimickit.util.errors import MimicKitError
from mimickit.util.paths import PROJECT_DATA_DIR, PROJECT_ROOT

DEMO_MODEL = PROJECT_DATA_DIR / "models" / "deepmimic_humanoid_demo_model.pt"
DEMO_ARGS = PROJECT_ROOT / "args" / "deepmimic_humanoid_demo_ppo_args.txt"


def test_the_arg_files_motion_file_is_read(tmp_path: Path) -> None:
    """A policy is compared on the arg file's --motion_file (as `mimickit test` runs it), so a missing
    clip there is one line naming it, before any engine is built."""
    arg_file = tmp_path / "args.txt"
    arg_file.write_text(DEMO_ARGS.read_text() + "\n--motion_file data/motions/no_such_clip.pkl\n")
    with pytest.raises(MimicKitError, match="--motion_file: file not found: data/motions/no_such_clip.pkl"):
        run_sim2sim(str(arg_file), model_file=str(DEMO_MODEL))
