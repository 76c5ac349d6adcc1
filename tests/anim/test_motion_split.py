"""A dataset split across processes as the reference splits it: the shares of a weighted
3-clip dataset for 1, 2 and 3 processes (and more processes than clips), the rounding and coverage
rule for many sizes, the zero-weight share error, and a real 2-process `mimickit train --devices cpu cpu`."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from mimickit.anim.mjcf_char_model import load_char_model
from mimickit.anim.motion import Motion, load_motion, save_motion
from mimickit.anim.motion_lib import MotionLib, process_share
from mimickit.util.errors import MimicKitError
from mimickit.util.paths import PROJECT_ROOT
from tests.conftest import DEMO_CLIP, PROJECT_HUMANOID

WEIGHTS = [1.0, 3.0, 6.0]


@pytest.fixture(scope="module")
def char():
    return load_char_model(PROJECT_HUMANOID)


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    """Three humanoid clips (the demo squat's first 20, 30 and 40 frames) with weights 1, 3, 6."""
    folder = tmp_path_factory.mktemp("ds")
    demo = load_motion(DEMO_CLIP)
    lines = ["motions:"]
    for i, (n, w) in enumerate(zip((20, 30, 40), WEIGHTS, strict=True)):
        save_motion(folder / f"c{i}.pkl", Motion(demo.loop_mode, demo.fps, demo.frames[:n]))
        lines.append(f"  - {{file: {folder / f'c{i}.pkl'}, weight: {w}}}")
    path = folder / "dataset.yaml"
    path.write_text("\n".join(lines) + "\n")
    return path


def shares(dataset: Path, char, num_procs: int) -> list[tuple[list[str], list[float]]]:
    """For each process: its clips' names and their sampling weights on that process."""
    out = []
    for rank in range(num_procs):
        lib = MotionLib(dataset, char, proc=(rank, num_procs))
        out.append(([Path(f).name for f in lib.motion_files], lib.get_motion_weights().tolist()))
    return out


@pytest.mark.parametrize(
    ("num_procs", "expected"),
    [
        (1, [(["c0.pkl", "c1.pkl", "c2.pkl"], [0.1, 0.3, 0.6])]),
        (2, [(["c0.pkl", "c1.pkl"], [0.25, 0.75]), (["c2.pkl"], [1.0])]),  # [0, round(1.5)=2), [2, 3)
        (3, [(["c0.pkl"], [1.0]), (["c1.pkl"], [1.0]), (["c2.pkl"], [1.0])]),
    ],
)
def test_three_clips_split_over_one_two_and_three_processes(dataset, char, num_procs, expected):
    got = shares(dataset, char, num_procs)
    assert [names for names, _ in got] == [names for names, _ in expected]
    for (_, w), (_, w_expected) in zip(got, expected, strict=True):
        assert w == pytest.approx(w_expected, rel=1e-6) and sum(w) == pytest.approx(1.0, rel=1e-6)
    union = [name for names, _ in got for name in names]
    assert sorted(union) == ["c0.pkl", "c1.pkl", "c2.pkl"], "every clip on exactly one process"


@pytest.mark.parametrize("num_procs", [4, 5])
def test_fewer_clips_than_processes_gives_every_process_the_whole_dataset(dataset, char, num_procs):
    for names, w in shares(dataset, char, num_procs):
        assert names == ["c0.pkl", "c1.pkl", "c2.pkl"]
        assert w == pytest.approx([0.1, 0.3, 0.6], rel=1e-6)


def test_the_split_rule_for_many_sizes_matches_the_reference_rounding():
    for m in range(1, 14):
        entries = [(Path(f"c{i}.pkl"), 1.0) for i in range(m)]
        for w in range(1, 14):
            got = [process_share(entries, r, w) for r in range(w)]
            if m < w:
                assert all(g == entries for g in got)
                continue
            # numpy's round (half to even), as the reference computes the bounds.
            bounds = [int(np.round(r * float(m) / w)) for r in range(w + 1)]
            assert got == [entries[bounds[r] : bounds[r + 1]] for r in range(w)], (m, w)
            assert all(got), f"{m} clips over {w} processes: each gets at least one"
            assert [e for g in got for e in g] == entries, "in order, each clip once"


def test_a_share_without_weight_is_an_error_naming_the_dataset_and_clips():
    entries = [(Path("a.pkl"), 1.0), (Path("b.pkl"), 0.0), (Path("c.pkl"), 0.0)]
    assert process_share(entries, 0, 2, "ds.yaml") == entries[:2]
    with pytest.raises(
        MimicKitError, match=r"ds.yaml: process 1 of 2 gets clips 2..2 \(c.pkl\), whose weights sum to 0"
    ):
        process_share(entries, 1, 2, "ds.yaml")


def test_clips_in_memory_are_never_split(char):
    demo = load_motion(DEMO_CLIP)
    lib = MotionLib([demo, demo, demo], char, weights=[1.0, 1.0, 2.0], proc=(1, 3))
    assert lib.num_motions() == 3
    torch.testing.assert_close(lib.get_motion_weights(), torch.tensor([0.25, 0.25, 0.5]))  # 1, 1, 2 over 4


@pytest.mark.integration
@pytest.mark.slow
def test_two_process_training_run_splits_the_dataset(dataset, tmp_path):
    """`mimickit train --devices cpu cpu` on the 3-clip dataset, one iteration: each process reports its
    share (process 0: c0, c1; process 1: c2) and the run finishes with its outputs."""
    out = tmp_path / "run"
    cmd = [
        sys.executable, "-m", "mimickit.cli", "train",
        "--arg_file", str(PROJECT_ROOT / "args/deepmimic_humanoid_demo_ppo_args.txt"), "--motion_file", str(dataset),
        "--devices", "cpu", "cpu", "--num_envs", "2", "--max_samples", "128", "--out_dir", str(out),
    ]  # fmt: skip
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=PROJECT_ROOT)
    assert r.returncode == 0, r.stderr[-3000:]
    assert f"process 0 of 2: 2 of the 3 clips of {dataset}: c0.pkl (1), c1.pkl (3)" in r.stderr, r.stderr[-3000:]
    assert f"process 1 of 2: 1 of the 3 clips of {dataset}: c2.pkl (6)" in r.stderr, r.stderr[-3000:]
    rows = [json.loads(line) for line in (out / "metrics.jsonl").read_text().splitlines()]
    assert rows and rows[-1]["samples"] >= 128
    assert json.loads((out / "args.json").read_text())["effective"]["world_size"] == 2
