"""Packaging hook: a wheel carries the project's files that live at the top of the source tree.

`data/` (characters, configs, the demo clip, shipped models), `args/` (arg files) and `web/` (the studio
page) stay at the repository root, where MimicKit keeps them and an editable install reads them. A
normal install has nowhere beside site-packages to put them, so `build_py` copies them into the
package as `mimickit/_share/`, which `mimickit.util.paths` takes as the project's root when it exists.
Everything else is declared in pyproject.toml.
"""

import shutil
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

ROOT = Path(__file__).resolve().parent
SHARED_FOLDERS = ("data", "args", "web")
SHARE = Path("mimickit") / "_share"  # mimickit.util.paths looks for this folder


class BuildPyWithProjectFiles(build_py):
    def run(self) -> None:
        super().run()
        if self.editable_mode:  # the editable install reads the checkout's own folders
            return
        dest = Path(self.build_lib) / SHARE
        shutil.rmtree(dest, ignore_errors=True)  # a stale build/ must not ship files deleted since
        for name in SHARED_FOLDERS:
            shutil.copytree(ROOT / name, dest / name, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))


setup(cmdclass={"build_py": BuildPyWithProjectFiles})
