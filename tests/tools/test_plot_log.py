"""`mimickit plot`: learning curves from log.txt and metrics.jsonl into a PNG."""

from __future__ import annotations

import json
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest

from mimickit import cli
from mimickit.tools.plot_log import curve, plot_logs, read_log
from mimickit.util.errors import MimicKitError

# matplotlib's first two default line colours: run 1 and run 2 of an overlay
C0, C1 = (0x1F, 0x77, 0xB4), (0xFF, 0x7F, 0x0E)


def write_metrics(path: Path, n: int = 20) -> Path:
    """metrics.jsonl as the Logger writes it: a test every 5 iterations, repeated in between."""
    rows = []
    for i in range(n):
        tested = i % 5 == 0
        rows.append({
            "iteration": i, "samples": 4096 * (i + 1), "wall_time": 0.01 * i,
            "test_return": 10.0 + (i // 5) * 5.0, "test_episode_length": 30.0 + 3 * (i // 5), "test_episodes": 128,
            "train_return": 8.0 + i, "train_episode_length": 24.0 + i, "train_episodes": 0 if i == 7 else 90,
            "reward_terms.pose": 0.3 + 0.01 * i, "clip_frac": None, "output": tested,
        })  # fmt: skip
    path.write_text("".join(json.dumps(r) + "\n" for r in rows))
    return path


def write_log_txt(path: Path, newline: str = "\n") -> Path:
    """log.txt in the reference's format: 25-wide columns, a header row, one row per output iteration."""
    header = ["Iteration", "Wall_Time", "Samples", "Test_Return", "Test_Episode_Length", "Test_Episodes",
              "Train_Return", "Train_Episode_Length", "Train_Episodes"]  # fmt: skip
    rows = [[i, 0.01 * i, 4096 * (i + 1), 12.0 + i, 40.0 + i, 128, 9.0 + 2 * i, 30.0 + i, 90] for i in range(0, 20, 5)]
    text = "".join("".join(str(v).ljust(25) for v in r).rstrip() + newline for r in [header, *rows])
    path.write_text(text)
    return path


def test_read_log_txt_lowercases_columns_and_reads_reference_line_ends(tmp_path: Path) -> None:
    cols = read_log(write_log_txt(tmp_path / "log.txt", newline="\r"))
    assert list(cols)[:4] == ["iteration", "wall_time", "samples", "test_return"]
    np.testing.assert_allclose(cols["test_return"], [12, 17, 22, 27])


def test_metrics_curves_skip_stale_tests_and_empty_iterations(tmp_path: Path) -> None:
    cols = read_log(write_metrics(tmp_path / "metrics.jsonl"))
    xs, ys = curve(cols, "iteration", "test_return", "m")
    np.testing.assert_allclose(xs, [0, 5, 10, 15])  # only the iterations that ran the test
    np.testing.assert_allclose(ys, [10, 15, 20, 25])
    xs, _ = curve(cols, "iteration", "train_return", "m")
    assert 7 not in xs and len(xs) == 19  # no train episode ended in iteration 7: its 0 is no value
    assert "clip_frac" in cols and np.isnan(cols["clip_frac"]).all()  # null (NaN) values stay a column


def test_plot_overlays_runs_one_subplot_per_column(tmp_path: Path) -> None:
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    metrics = write_metrics(tmp_path / "a" / "metrics.jsonl")
    log = write_log_txt(tmp_path / "b" / "log.txt")
    out = tmp_path / "plots" / "curves.png"
    size = plot_logs([metrics, log], out, x="samples", columns=["Test_Return", "train_return"])
    img = iio.imread(out)
    assert img.shape[:2] == (size[1], size[0]) == (480, 800)  # 2 subplots of 2.4 in at 100 dpi, 8 in wide
    rgb = img[..., :3].astype(int)
    assert rgb.std() > 10
    for colour in (C0, C1):  # both runs were drawn
        assert (np.abs(rgb - colour).sum(-1) < 30).sum() > 100, colour


def test_plot_accepts_run_folders_and_default_columns(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    write_metrics(tmp_path / "metrics.jsonl")
    out = tmp_path / "p.png"
    assert cli.main(["plot", str(tmp_path), "--out", str(out), "--x", "iteration"]) == 0
    assert iio.imread(out).shape[:2] == (960, 800)  # the 4 default columns
    assert "wrote" in capsys.readouterr().out


def test_missing_column_is_one_error_naming_it(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    log = write_log_txt(tmp_path / "log.txt")
    out = tmp_path / "p.png"
    assert cli.main(["plot", str(log), "--out", str(out), "--y", "test_return", "disc_loss"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "'disc_loss'" in err and str(log) in err and "\n" not in err
    assert not out.exists()


def test_a_column_only_one_run_has_is_drawn_for_that_run(tmp_path: Path) -> None:
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    metrics = write_metrics(tmp_path / "a" / "metrics.jsonl")  # has reward_terms.pose
    log = write_log_txt(tmp_path / "b" / "log.txt")  # has not
    out = tmp_path / "p.png"
    plot_logs([metrics, log], out, x="samples", columns=["reward_terms.pose"])
    rgb = iio.imread(out)[..., :3].astype(int)
    assert (np.abs(rgb - C0).sum(-1) < 30).sum() > 100  # run a's line
    assert (np.abs(rgb - C1).sum(-1) < 30).sum() == 0  # no line for run b
    with pytest.raises(MimicKitError, match=r"metrics.jsonl, .*log.txt: no column 'disc_loss'"):
        plot_logs([metrics, log], tmp_path / "q.png", columns=["disc_loss"])


def test_bad_files_are_errors_naming_the_file(tmp_path: Path) -> None:
    with pytest.raises(MimicKitError, match="log file not found: .*nope.txt"):
        read_log(tmp_path / "nope.txt")
    bad = tmp_path / "log.txt"
    bad.write_text("Iteration Samples\n0 4096\n1\n")
    with pytest.raises(MimicKitError, match=r"log.txt: row 3 has 1 values, the header has 2"):
        read_log(bad)
    bad_json = tmp_path / "metrics.jsonl"
    bad_json.write_text('{"iteration": 0}\n{oops\n{"iteration": 2}\n')
    with pytest.raises(MimicKitError, match=r"metrics.jsonl: line 2 is not JSON"):
        read_log(bad_json)
    (tmp_path / "empty_dir").mkdir()
    with pytest.raises(MimicKitError, match=r"empty_dir: no metrics.jsonl or log.txt"):
        read_log(tmp_path / "empty_dir")


def test_half_written_last_line_is_left_out(tmp_path: Path) -> None:
    path = write_metrics(tmp_path / "metrics.jsonl", n=3)
    with path.open("a") as f:
        f.write('{"iteration": 3, "samp')  # the trainer is writing it right now
    assert len(read_log(path)["iteration"]) == 3
