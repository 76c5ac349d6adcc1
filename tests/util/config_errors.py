"""What the config-loader tests share: the one error line a loader gives for a yaml file."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest

from mimickit.util.errors import MimicKitError


def load_error(
    tmp_path: Path, text: str, load: Callable[[Path], object], name: str = "config.yaml"
) -> tuple[Path, str]:
    """Write `text` to tmp_path/name, load it with `load` (which must refuse it with a MimicKitError)
    and return the file and the error's message."""
    f = tmp_path / name
    f.write_text(text)
    with pytest.raises(MimicKitError) as e:
        load(f)
    return f, str(e.value)
