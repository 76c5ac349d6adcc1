"""A normal (non-editable) install works away from the checkout: the wheel carries `data/`, `args/` and
`web/`, and both commands find them from any folder.

The wheel is built from a copy of the working tree (tracked and new files, as git sees them) and
installed with `--no-deps` into a fresh venv in tmp whose dependencies come from the test's own
interpreter through a `.pth` line, so nothing is downloaded. Only the site-packages folder is added:
its editable-install hook (a `.pth` file there) is not run, so `mimickit` can only come from the wheel.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
import threading
from pathlib import Path

import httpx
import pytest

from mimickit.util.paths import IMPORT_ROOT

pytestmark = pytest.mark.integration

TIMEOUT_S = 300
DEMO_ARGS = "args/deepmimic_humanoid_demo_ppo_args.txt"


def run(argv: list[str | Path], cwd: Path, timeout: float = TIMEOUT_S) -> subprocess.CompletedProcess:
    proc = subprocess.run(
        list(map(str, argv)), cwd=cwd, env=clean_env(), capture_output=True, text=True, timeout=timeout
    )
    assert proc.returncode == 0, (
        f"{' '.join(map(str, argv))}: exit {proc.returncode}\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
    )
    return proc


def clean_env() -> dict[str, str]:
    """The environment without a PYTHONPATH that could point back into the checkout."""
    return {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}


def copy_working_tree(dest: Path) -> None:
    listed = subprocess.run(
        ["git", "-C", str(IMPORT_ROOT), "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    for rel in filter(None, listed.split("\0")):
        src = IMPORT_ROOT / rel
        if src.is_file():  # a tracked file deleted in the working tree is not copied
            (dest / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dest / rel)


class Installed:
    """A fresh venv with the package installed from its wheel, and a folder outside the checkout."""

    def __init__(self, root: Path) -> None:
        src, wheels, self.venv, self.elsewhere = (root / n for n in ("src", "wheels", "venv", "elsewhere"))
        self.elsewhere.mkdir()
        copy_working_tree(src)
        run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation", "-w", wheels, src], root)
        (wheel,) = wheels.glob("mimickit_studio-*.whl")
        run([sys.executable, "-m", "venv", "--without-pip", self.venv], root)
        self.python = self.venv / "bin" / "python"
        site = Path(
            run([self.python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"], root).stdout.strip()
        )
        ours = sysconfig.get_paths()
        (site / "_mimickit_deps.pth").write_text(f"{ours['purelib']}\n{ours['platlib']}\n")
        run(
            [sys.executable, "-m", "pip", "--python", self.python, "install", "-q", "--no-deps", "--no-index", wheel],
            root,
        )
        self.site = site

    def bin(self, name: str) -> Path:
        return self.venv / "bin" / name


@pytest.fixture(scope="module")
def installed(tmp_path_factory: pytest.TempPathFactory) -> Installed:
    return Installed(tmp_path_factory.mktemp("install"))


def test_the_package_imports_from_the_wheel(installed: Installed) -> None:
    code = (
        "import mimickit, studio, mimickit.util.paths as p; print(mimickit.__file__, studio.__file__, p.PROJECT_ROOT)"
    )
    files = run([installed.python, "-c", code], installed.elsewhere).stdout.split()
    assert all(Path(f).is_relative_to(installed.site) for f in files), files
    assert Path(files[2]) == installed.site / "mimickit" / "_share"


def test_the_studio_serves_the_page_and_the_demo_clip(installed: Installed) -> None:
    argv = [installed.bin("mimickit-studio"), "serve", "--port", "0", "--viser-port", "0"]
    err_file = installed.elsewhere / "studio.stderr.log"
    with open(err_file, "w") as err:
        proc = subprocess.Popen(
            argv, cwd=installed.elsewhere, env=clean_env(), stdout=subprocess.PIPE, stderr=err, text=True
        )
    watchdog = threading.Timer(120, proc.kill)  # a server that never prints its address must not hang the test
    watchdog.start()
    try:
        line = proc.stdout.readline()
        watchdog.cancel()
        assert "http://" in line, f"studio did not start: {line!r}\n{err_file.read_text()[-3000:]}"
        with httpx.Client(base_url=line.split()[-1], timeout=30.0) as client:
            page = client.get("/")
            assert page.status_code == 200 and "<html" in page.text
            assert client.get("/web/main.js").status_code == 200
            assert client.get("/web/vendor/uPlot.esm.js").status_code == 200  # the page's plots, vendored
            motions = client.get("/api/motions").json()
        assert "data/motions/humanoid_demo_squat.pkl" in [m["path"] for m in motions], motions
        # The runs folder defaults to the working directory's output/, not into site-packages.
        assert (installed.elsewhere / "output" / "studio_runs" / "registry.sqlite").is_file()
    finally:
        watchdog.cancel()
        proc.kill()
        proc.wait()


def test_a_training_on_the_demo_arg_file_finishes(installed: Installed) -> None:
    out = installed.elsewhere / "run"
    argv = [installed.bin("mimickit"), "train", "--arg_file", DEMO_ARGS, "--num_envs", "4", "--max_samples", "1"]
    proc = run([*argv, "--out_dir", out], installed.elsewhere)
    assert "finished: reached max_samples" in proc.stdout + proc.stderr
    assert (out / "model.pt").is_file()
    effective = json.loads((out / "args.json").read_text())["effective"]
    assert Path(effective["env_config"]).is_relative_to(installed.site / "mimickit" / "_share" / "data")
