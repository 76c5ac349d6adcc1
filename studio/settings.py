"""What one `mimickit-studio serve` process is configured with."""

from __future__ import annotations

import ipaddress
import shlex
import sys
from dataclasses import dataclass, field
from pathlib import Path

from mimickit.util.paths import PROJECT_DATA_DIR, PROJECT_ROOT, DataPaths, default_output_root

DEFAULT_TRAINER = [sys.executable, "-m", "mimickit.cli", "train"]
DEMO_CLIP = PROJECT_DATA_DIR / "motions" / "humanoid_demo_squat.pkl"
DEMO_CHAR = PROJECT_DATA_DIR / "assets" / "humanoid" / "humanoid.xml"


@dataclass
class Settings:
    """Server settings; paths are resolved absolute by `resolved()`."""

    host: str = "127.0.0.1"
    port: int = 8000
    viser_port: int = 0  # 0: pick a free port
    data_dir: Path | None = None  # a user's MimicKit-style data folder (motions/, assets/, ...)
    runs_dir: Path = field(default_factory=lambda: default_output_root() / "output" / "studio_runs")
    token: str | None = None
    allowed_hosts: list[str] = field(default_factory=list)
    """Host header names accepted besides the bound host's (`--allowed-hosts`; `*`: any)."""
    max_concurrent_runs: int = 1
    trainer: list[str] = field(default_factory=lambda: list(DEFAULT_TRAINER))
    """The program a run starts, before its `--arg_file ...` arguments (`mimickit train` by default)."""
    executor: str = "local"
    """What runs the trainers: `local` (subprocesses of the server) or `ray` (jobs on `ray_address`)."""
    ray_address: str = "http://127.0.0.1:8265"
    """The Ray cluster's dashboard address (its Job Submission API), for `executor="ray"`."""
    upload_limit_bytes: int = 64 * 1024 * 1024
    stop_timeout_s: float = 60.0
    """How long a stopped run may take to write its checkpoint before it is killed."""
    max_queued_runs: int = 1000
    """Training runs that may wait in the queue at once; a launch or sweep past it is refused (429)."""
    max_queued_jobs: int = 20
    """Eval jobs, and video jobs, that may wait in their queue at once; one more is refused (429)."""
    eval_time_limit_s: float = 3600.0
    """An eval job running longer than this is killed and fails."""
    video_time_limit_s: float = 600.0
    """A video job running longer than this is killed and fails."""
    replay_quota_bytes: int = 1024**3
    """What `<runs-dir>/replays/` may hold; an export past it is refused until old replays are deleted."""
    start_viser: bool = True
    startup_clip: Path | None = DEMO_CLIP
    startup_char: Path | None = DEMO_CHAR
    """The clip playing when the page first opens, on `startup_char` (guessed from the clip's frame
    width when None); no clip: an empty scene."""

    def resolved(self) -> Settings:
        self.runs_dir = Path(self.runs_dir).expanduser().resolve()
        for name in ("startup_clip", "startup_char"):
            if getattr(self, name) is not None:
                setattr(self, name, Path(getattr(self, name)).expanduser().resolve())
        if self.data_dir is not None:
            self.data_dir = Path(self.data_dir).expanduser().resolve()
        return self

    @property
    def data_paths(self) -> DataPaths:
        """How this server's builds find `data/...` files: the user's data folder, then the project's."""
        return DataPaths(self.data_dir)

    @property
    def data_dirs(self) -> list[Path]:
        """The user's data folder first (it shadows the project's, as in `DataPaths.resolve`)."""
        return self.data_paths.dirs()

    @property
    def arg_dirs(self) -> list[Path]:
        """Folders with MimicKit arg files: the project's `args/`, each data folder's, and the runs folder's."""
        return [PROJECT_ROOT / "args", *(d / "args" for d in self.data_dirs), self.runs_dir / "args"]

    @property
    def uploads_dir(self) -> Path:
        return self.runs_dir / "uploads"

    @property
    def readable_roots(self) -> list[Path]:
        """Every folder a request may name a file in."""
        return [*self.data_dirs, PROJECT_ROOT / "args", self.runs_dir]

    @property
    def needs_token(self) -> bool:
        return not is_loopback(self.host)


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def parse_trainer(text: str) -> list[str]:
    return shlex.split(text)
