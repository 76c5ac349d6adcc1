"""The run registry: one SQLite table in `<runs-dir>/registry.sqlite` (stdlib sqlite3, WAL mode).

The registry is the truth about runs across server restarts; the run manager is its only writer.
Each call opens its own short connection, so any thread may use it and a killed server leaves
nothing half-written (SQLite's journal takes care of that). A full or read-only disk is a `DiskError`
(one line, HTTP 507 or 503); reads go on working on a full disk (see `_keep_wal_index`).
"""

from __future__ import annotations

import contextlib
import json
import sqlite3
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field, fields
from enum import Enum
from pathlib import Path
from typing import Any

from studio.disk import disk_error, require_space


class RunStatus(str, Enum):
    """queued/running/stopping/interrupted are the studio's; the four end states are the run folder's
    (`mimickit.learning.run_folder.EndState`), read from its state.json when the trainer exits."""

    QUEUED = "queued"
    RUNNING = "running"
    STOPPING = "stopping"
    FINISHED = "finished"  # reached its max_samples
    STOPPED = "stopped"
    DIVERGED = "diverged"
    FAILED = "failed"
    INTERRUPTED = "interrupted"  # its server died while it ran

    @classmethod
    def _missing_(cls, value: object) -> RunStatus | None:
        # A registry of an earlier studio called a run that exited 0 "succeeded".
        return cls.FINISHED if value == "succeeded" else None

    @property
    def finished(self) -> bool:
        return self in FINISHED


MAX_ID = 2**63 - 1  # SQLite's largest integer: a larger id names no run (and must not reach a query)
FINISHED = {RunStatus.FINISHED, RunStatus.STOPPED, RunStatus.DIVERGED, RunStatus.FAILED, RunStatus.INTERRUPTED}
ACTIVE = {RunStatus.RUNNING, RunStatus.STOPPING}

_SCHEMA = """
CREATE TABLE IF NOT EXISTS runs (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    name TEXT NOT NULL,
    config TEXT NOT NULL,          -- JSON: arg_file and overrides, as the user asked
    status TEXT NOT NULL,
    pid INTEGER,
    created_at REAL NOT NULL,
    started_at REAL,
    ended_at REAL,
    out_dir TEXT NOT NULL,
    exit_code INTEGER,
    command TEXT,                  -- JSON argv of the latest process, recorded for reproducibility
    attempts INTEGER NOT NULL DEFAULT 0,
    reason TEXT,                   -- the line that says why it ended (diverged/failed), from the run folder
    executor TEXT NOT NULL DEFAULT 'local',  -- what runs its processes: local (subprocesses) or ray (Ray jobs)
    job_id TEXT,                   -- the executor's id of the latest process: a pid, a Ray submission id
    sweep_id INTEGER,              -- the sweep it belongs to (one group in the run list), or NULL
    tags TEXT NOT NULL DEFAULT '[]',  -- JSON list of the user's short labels (the run list filters by them)
    notes TEXT NOT NULL DEFAULT ''    -- the user's free text about the run
);
CREATE TABLE IF NOT EXISTS sweeps (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    name TEXT NOT NULL,
    spec TEXT NOT NULL,            -- JSON: the arg file, the lists of values and the shared overrides
    created_at REAL NOT NULL
)
"""
# Columns added after the first release: (name, declaration), added to an older registry when opened.
_ADDED_COLUMNS = [
    ("reason", "TEXT"),
    ("executor", "TEXT NOT NULL DEFAULT 'local'"),
    ("job_id", "TEXT"),
    ("sweep_id", "INTEGER"),
    ("tags", "TEXT NOT NULL DEFAULT '[]'"),
    ("notes", "TEXT NOT NULL DEFAULT ''"),
]


@dataclass
class Run:
    id: int
    name: str
    config: dict[str, Any]
    status: RunStatus
    pid: int | None
    created_at: float
    started_at: float | None
    ended_at: float | None
    out_dir: str
    exit_code: int | None
    command: list[str] | None
    attempts: int
    reason: str | None = None
    executor: str = "local"
    job_id: str | None = None
    sweep_id: int | None = None
    tags: list[str] = field(default_factory=list)
    notes: str = ""

    def to_json(self) -> dict[str, Any]:
        """The fields as JSON values; `config` and `command` are this run's own (not copied: a run list
        of thousands is built on every poll, and asdict's deep copies were most of its cost)."""
        d = {f.name: getattr(self, f.name) for f in fields(self)}
        d["status"] = self.status.value
        return d


class Registry:
    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._lock = threading.Lock()  # one writer at a time inside this process
        self._writes = 0  # grows with every write through this registry: what a cached read checks
        self.on_write: Callable[[], None] = _nothing  # called after each write (the stream's run list wakes)
        with self._connect() as db:
            db.execute("PRAGMA journal_mode=WAL")
            db.executescript(_SCHEMA)
            have = {row["name"] for row in db.execute("PRAGMA table_info(runs)")}
            for name, decl in _ADDED_COLUMNS:
                if name not in have:
                    db.execute(f"ALTER TABLE runs ADD COLUMN {name} {decl}")
        self._keeper = self._keep_wal_index()

    def _keep_wal_index(self) -> sqlite3.Connection:
        """A connection held open while the registry lives. SQLite deletes the WAL's index file (`-shm`)
        when its last connection closes, and the next one must create it again: on a full disk that
        fails, and every read would answer 'disk I/O error'."""
        keeper = sqlite3.connect(self.path, check_same_thread=False)
        keeper.execute("SELECT 1 FROM runs LIMIT 1").fetchall()  # a read maps the index; it stays
        return keeper

    def close(self) -> None:
        self._keeper.close()

    @property
    def writes(self) -> int:
        """How many writes this registry has made: a cache of a read is current while it has not grown
        (the run manager, this process's, is the only writer)."""
        return self._writes

    @contextmanager
    def _write(self) -> Iterator[sqlite3.Connection]:
        """A connection for a write, one writer at a time; `writes` grows once it has committed (or
        failed: a reader then reads again, which is never wrong)."""
        with self._lock:
            try:
                with self._connect() as db:
                    yield db
                self._reuse_wal()
            finally:
                self._writes += 1
                self.on_write()

    def _reuse_wal(self) -> None:
        """Copy the committed pages into the database file, so that the next write starts the WAL from
        its beginning, over space the file already has: a run's end is still recorded on a full disk.
        Best effort: when it cannot (the database file would grow), the WAL grows as without it."""
        with contextlib.suppress(sqlite3.Error):  # also a keeper closed by a server shutting down
            self._keeper.execute("PRAGMA wal_checkpoint(PASSIVE)").fetchall()

    @contextmanager
    def _connect(self) -> Iterator[sqlite3.Connection]:
        """A short connection; a full or read-only disk is a `DiskError` naming the registry's file."""
        try:
            db = sqlite3.connect(self.path, timeout=10.0)
            db.row_factory = sqlite3.Row
            try:
                with db:  # commits on success, rolls back on error
                    yield db
            finally:
                db.close()
        except sqlite3.OperationalError as e:
            found = disk_error(e, f"the run registry {self.path}")
            if found is None:
                raise
            raise found from e

    def create(
        self,
        name: str,
        config: dict[str, Any],
        out_dir_for: Callable[[int], str],
        *,
        executor: str = "local",
        sweep_id: int | None = None,
    ) -> Run:
        """Insert a queued run; its out_dir comes from its new id, in the same transaction, so no
        reader (the run manager's thread) ever sees a queued run without its folder. Refused (DiskError)
        when the runs folder's disk has no room for a run, though SQLite could still add the row."""
        require_space(self.path.parent, "queue a run")
        with self._write() as db:
            cur = db.execute(
                "INSERT INTO runs (name, config, status, created_at, out_dir, executor, sweep_id)"
                " VALUES (?, ?, ?, ?, '', ?, ?)",
                (name, json.dumps(config), RunStatus.QUEUED.value, time.time(), executor, sweep_id),
            )
            run_id = int(cur.lastrowid)
            db.execute("UPDATE runs SET out_dir = ? WHERE id = ?", (out_dir_for(run_id), run_id))
        return self.get(run_id)

    def update(self, run_id: int, **fields: Any) -> Run:
        """Set columns of one run; `config`/`command`/`tags` are stored as JSON, `status` as its value."""
        if not fields:
            return self.get(run_id)
        cols, vals = [], []
        for key, value in fields.items():
            if key in ("config", "command", "tags") and value is not None:
                value = json.dumps(value)
            elif isinstance(value, RunStatus):
                value = value.value
            cols.append(f"{key} = ?")
            vals.append(value)
        with self._write() as db:
            db.execute(f"UPDATE runs SET {', '.join(cols)} WHERE id = ?", (*vals, run_id))
        return self.get(run_id)

    def get(self, run_id: int) -> Run:
        run = self.find(run_id)
        if run is None:
            raise KeyError(run_id)
        return run

    def find(self, run_id: int) -> Run | None:
        if not 0 <= run_id <= MAX_ID:
            return None
        with self._connect() as db:
            row = db.execute("SELECT * FROM runs WHERE id = ?", (run_id,)).fetchone()
        return _row_to_run(row) if row else None

    def list(self, status: RunStatus | None = None) -> list[Run]:
        with self._connect() as db:
            if status is None:
                rows = db.execute("SELECT * FROM runs ORDER BY id").fetchall()
            else:
                rows = db.execute("SELECT * FROM runs WHERE status = ? ORDER BY id", (status.value,)).fetchall()
        return [_row_to_run(r) for r in rows]

    def count(self, status: RunStatus) -> int:
        with self._connect() as db:
            return int(db.execute("SELECT COUNT(*) FROM runs WHERE status = ?", (status.value,)).fetchone()[0])

    def unsubmitted(self, limit: int) -> list[Run]:
        """The oldest `limit` queued runs no executor has yet (no job id): what the manager starts next."""
        with self._connect() as db:
            rows = db.execute(
                "SELECT * FROM runs WHERE status = ? AND job_id IS NULL ORDER BY id LIMIT ?",
                (RunStatus.QUEUED.value, limit),
            ).fetchall()
        return [_row_to_run(r) for r in rows]

    def of_ids(self, ids: list[int]) -> list[Run]:
        """The runs of `ids` that exist (ids past SQLite's integers name none), in id order."""
        wanted = sorted({i for i in ids if 0 <= i <= MAX_ID})
        rows = []
        with self._connect() as db:
            for start in range(0, len(wanted), 500):  # under SQLite's limit of bound parameters
                chunk = wanted[start : start + 500]
                marks = ",".join("?" * len(chunk))
                rows += db.execute(f"SELECT * FROM runs WHERE id IN ({marks}) ORDER BY id", chunk).fetchall()
        return [_row_to_run(r) for r in rows]

    def of_sweep(self, sweep_id: int) -> list[Run]:
        if not 0 <= sweep_id <= MAX_ID:
            return []
        with self._connect() as db:
            rows = db.execute("SELECT * FROM runs WHERE sweep_id = ? ORDER BY id", (sweep_id,)).fetchall()
        return [_row_to_run(r) for r in rows]

    def stop_queued(self, ids: list[int], ended_at: float) -> int:
        """Mark the runs of `ids` that are queued without a job stopped, in one transaction: they never
        start. How many were."""
        done = 0
        with self._write() as db:
            for start in range(0, len(ids), 500):
                chunk = ids[start : start + 500]
                marks = ",".join("?" * len(chunk))
                cur = db.execute(
                    f"UPDATE runs SET status = ?, ended_at = ? WHERE id IN ({marks}) AND status = ? AND job_id IS NULL",
                    (RunStatus.STOPPED.value, ended_at, *chunk, RunStatus.QUEUED.value),
                )
                done += cur.rowcount
        return done

    def delete(self, run_id: int) -> None:
        with self._write() as db:
            db.execute("DELETE FROM runs WHERE id = ?", (run_id,))

    def create_sweep(self, name: str, spec: dict[str, Any]) -> int:
        """A new sweep (a named group of runs); its runs name it with `sweep_id`."""
        require_space(self.path.parent, "queue a sweep")
        with self._write() as db:
            cur = db.execute(
                "INSERT INTO sweeps (name, spec, created_at) VALUES (?, ?, ?)", (name, json.dumps(spec), time.time())
            )
            return int(cur.lastrowid)

    def sweep(self, sweep_id: int) -> dict[str, Any] | None:
        """One sweep with the ids of its runs, or None."""
        if not 0 <= sweep_id <= MAX_ID:
            return None
        with self._connect() as db:
            row = db.execute("SELECT * FROM sweeps WHERE id = ?", (sweep_id,)).fetchone()
            members = db.execute("SELECT id FROM runs WHERE sweep_id = ? ORDER BY id", (sweep_id,)).fetchall()
        if row is None:
            return None
        return {**dict(row), "spec": json.loads(row["spec"]), "run_ids": [m["id"] for m in members]}

    def sweeps(self) -> list[dict[str, Any]]:
        """Every sweep with the ids of its runs, oldest first."""
        with self._connect() as db:
            rows = db.execute("SELECT * FROM sweeps ORDER BY id").fetchall()
            members = db.execute("SELECT id, sweep_id FROM runs WHERE sweep_id IS NOT NULL ORDER BY id").fetchall()
        out = [{**dict(r), "spec": json.loads(r["spec"]), "run_ids": []} for r in rows]
        by_id = {s["id"]: s for s in out}
        for m in members:
            if m["sweep_id"] in by_id:
                by_id[m["sweep_id"]]["run_ids"].append(m["id"])
        return out


def _row_to_run(row: sqlite3.Row) -> Run:
    d = dict(row)
    d["config"] = json.loads(d["config"])
    d["command"] = json.loads(d["command"]) if d["command"] else None
    d["status"] = RunStatus(d["status"])
    d["tags"] = json.loads(d["tags"])
    return Run(**d)


def _nothing() -> None:
    pass
