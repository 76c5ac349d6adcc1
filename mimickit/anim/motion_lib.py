"""MotionLib: a set of clips on one character, sampled and interpolated in batches, as the reference's.

All clips are concatenated along frames. Per frame it keeps root position/rotation, joint rotations
and finite-difference velocities; queries take motion ids and times as tensors `[n]` and return
batched tensors `[n, ...]`. Under several processes each loads only its share of a dataset
(`process_share`).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import torch

from mimickit.anim.kin_char_model import KinCharModel
from mimickit.anim.motion import LoopMode, Motion, load_motion
from mimickit.util import ranks
from mimickit.util import torch_util as tu
from mimickit.util.config import ConfigModel, load_config
from mimickit.util.errors import MimicKitError
from mimickit.util.paths import PROJECT_DATA, DataPaths


class DatasetEntry(ConfigModel):
    file: str
    weight: float = 1.0


class DatasetConfig(ConfigModel):
    motions: list[DatasetEntry]


@dataclass
class MotionFrame:
    """A batch of reference states, each field `[n, ...]`."""

    root_pos: torch.Tensor  # [n, 3]
    root_rot: torch.Tensor  # [n, 4] xyzw
    root_vel: torch.Tensor  # [n, 3] world frame, origin velocity
    root_ang_vel: torch.Tensor  # [n, 3] world frame
    joint_rot: torch.Tensor  # [n, J-1, 4] local
    dof_vel: torch.Tensor  # [n, D]


def load_motion_list(motion_file: str | Path, data_paths: DataPaths = PROJECT_DATA) -> list[tuple[Path, float]]:
    """(clip path, weight) pairs: a dataset yaml lists clips with weights; anything else is one clip.
    The file and a dataset's entries (`data/motions/...`) are found by `data_paths`."""
    path = data_paths.resolve(motion_file)
    if path.suffix in (".yaml", ".yml"):
        cfg = load_config(DatasetConfig, path)
        if not cfg.motions:
            raise MimicKitError(f"{path}: the dataset lists no motions")
        out = []
        for i, entry in enumerate(cfg.motions):
            if entry.weight < 0:
                raise MimicKitError(f"{path}: motions[{i}].weight must be >= 0, got {entry.weight}")
            clip = data_paths.resolve(entry.file)
            if not clip.is_file():
                raise MimicKitError(f"{path}: motions[{i}].file not found: {entry.file}")
            out.append((clip, entry.weight))
        return out
    if not path.is_file():
        raise MimicKitError(f"motion file not found: {motion_file}")
    return [(path, 1.0)]


def process_share(
    entries: list[tuple[Path, float]], rank: int, num_procs: int, source: str | Path = "the dataset"
) -> list[tuple[Path, float]]:
    """The clips process `rank` of `num_procs` trains on, as the reference splits a dataset:
    with M ≥ num_procs clips, process r keeps clips [round(r·M/W), round((r+1)·M/W)) (W = num_procs;
    round half to even, as numpy's), so every clip goes to exactly one process and each gets at least
    one; their weights are re-normalised by MotionLib to sum to 1 on that process. With fewer clips than
    processes (M < W) nothing is split: every process samples the whole dataset with its weights (the
    reference's behaviour). A share whose weights sum to 0 is an error naming `source` and the clips."""
    m = len(entries)
    if num_procs <= 1 or m < num_procs:
        return list(entries)
    begin, end = round(rank * m / num_procs), round((rank + 1) * m / num_procs)
    share = entries[begin:end]
    if sum(w for _, w in share) <= 0:
        names = ", ".join(p.name for p, _ in share)
        raise MimicKitError(
            f"{source}: process {rank} of {num_procs} gets clips {begin}..{end - 1} ({names}), whose weights "
            f"sum to 0 (each process samples only its share of a dataset): give them weight or reorder the clips"
        )
    return share


def _report_share(
    source: str | Path, rank: int, num_procs: int, entries: list[tuple[Path, float]], share: list[tuple[Path, float]]
) -> None:
    """One stderr line per process: which of the dataset's clips it samples (a run's log shows the split)."""
    names = ", ".join(f"{p.name} ({w:g})" for p, w in share)
    which = "all" if len(share) == len(entries) else f"{len(share)}"
    print(
        f"process {rank} of {num_procs}: {which} of the {len(entries)} clips of {source}: {names}",
        file=sys.stderr,
        flush=True,
    )


class MotionLib:
    def __init__(
        self,
        motion_file: str | Path | list[Motion],
        char_model: KinCharModel,
        device: torch.device | str = "cpu",
        weights: list[float] | None = None,
        proc: tuple[int, int] | None = None,
        data_paths: DataPaths = PROJECT_DATA,
    ) -> None:
        """A clip, a dataset yaml, or clips in memory with their weights (never split). A dataset is
        split across processes by `process_share`, as the reference does under several `--devices`:
        `proc` = (rank, num_procs) whose share to load, by default this process's (util.ranks)."""
        self.char_model = char_model
        self.device = torch.device(device)
        if isinstance(motion_file, (str, Path)):
            rank, num_procs = proc or (ranks.get_proc_rank(), ranks.get_num_procs())
            entries = load_motion_list(motion_file, data_paths)
            share = process_share(entries, rank, num_procs, motion_file)
            if num_procs > 1 and len(entries) > 1:
                _report_share(motion_file, rank, num_procs, entries, share)
            entries = share
            motions = [load_motion(p) for p, _ in entries]
            weights = [w for _, w in entries]
            self.motion_files = [str(p) for p, _ in entries]
        else:
            motions = list(motion_file)
            weights = weights or [1.0] * len(motions)
            self.motion_files = ["<memory>"] * len(motions)
        self._load(motions, weights)

    # ------------------------------------------------------------------ loading
    def _load(self, motions: list[Motion], weights: list[float]) -> None:
        frame_size = 6 + self.char_model.get_dof_size()
        for m, f in zip(motions, self.motion_files, strict=True):
            if m.frame_dim != frame_size:
                raise MimicKitError(
                    f"{f}: frames have {m.frame_dim} columns but the character "
                    f"{self.char_model.source} needs {frame_size} (6 + {self.char_model.get_dof_size()} DoFs)"
                )
        w = torch.tensor(weights, dtype=torch.float32, device=self.device)
        if w.sum() <= 0:
            raise MimicKitError("motion weights sum to zero")
        self._weights = w / w.sum()
        dev = self.device
        self._fps = torch.tensor([m.fps for m in motions], dtype=torch.float32, device=dev)
        self._num_frames = torch.tensor([m.num_frames for m in motions], dtype=torch.long, device=dev)
        self._length = (self._num_frames - 1).float() / self._fps
        self._loop_mode = torch.tensor([int(m.loop_mode) for m in motions], dtype=torch.long, device=dev)
        self._start = torch.cumsum(self._num_frames, 0) - self._num_frames

        frames = torch.cat([torch.as_tensor(m.frames, dtype=torch.float32) for m in motions]).to(dev)
        self.root_pos = frames[:, 0:3].contiguous()
        root_rot = tu.quat_pos(tu.exp_map_to_quat(frames[:, 3:6]))
        joint_rot = tu.quat_pos(self.char_model.dof_to_rot(frames[:, 6:]))
        # Root and joint rotations side by side [F, J, 4], so that a frame query slerps them in one go.
        self._rots = torch.cat([root_rot.unsqueeze(1), joint_rot], dim=1)
        self.root_rot, self.joint_rot = self._rots[:, 0], self._rots[:, 1:]
        self.dof_pos = self.char_model.rot_to_dof(self.joint_rot)
        self._compute_velocities(motions)

    def _compute_velocities(self, motions: list[Motion]) -> None:
        n = self.root_pos.shape[0]
        fps = torch.repeat_interleave(self._fps, self._num_frames).unsqueeze(-1)
        nxt = torch.clamp(torch.arange(n, device=self.device) + 1, max=n - 1)
        self.root_vel = fps * (self.root_pos[nxt] - self.root_pos)
        drot = tu.quat_mul(self.root_rot[nxt], tu.quat_conjugate(self.root_rot))
        self.root_ang_vel = fps * tu.quat_to_exp_map(drot)
        self.dof_vel = self.char_model.compute_dof_vel(self.joint_rot, self.joint_rot[nxt], 1.0) * fps
        # The last frame of each clip would difference into the next clip: copy its predecessor.
        last = self._start + self._num_frames - 1
        prev = torch.clamp(last - 1, min=0)
        prev = torch.maximum(prev, self._start)
        for buf in (self.root_vel, self.root_ang_vel, self.dof_vel):
            buf[last] = buf[prev]
        single = self._num_frames == 1
        for buf in (self.root_vel, self.root_ang_vel, self.dof_vel):
            buf[last[single]] = 0.0
        wrap = self.root_pos[last] - self.root_pos[self._start]
        wrap[:, 2] = 0.0
        self._wrap_delta = torch.where((self._loop_mode == LoopMode.WRAP).unsqueeze(-1), wrap, torch.zeros_like(wrap))

    # ------------------------------------------------------------------ queries
    def num_motions(self) -> int:
        return int(self._num_frames.shape[0])

    def get_num_motions(self) -> int:
        return self.num_motions()

    def get_total_length(self) -> float:
        return float(self._length.sum())

    def get_motion_weights(self) -> torch.Tensor:
        return self._weights

    def get_motion_length(self, ids: torch.Tensor) -> torch.Tensor:
        return self._length[ids]

    def get_motion_loop_mode(self, ids: torch.Tensor) -> torch.Tensor:
        return self._loop_mode[ids]

    def get_motion_fps(self, ids: torch.Tensor) -> torch.Tensor:
        return self._fps[ids]

    def get_motion_frame_size(self) -> int:
        return 6 + self.char_model.get_dof_size()

    def sample_motions(self, n: int, generator: torch.Generator | None = None) -> torch.Tensor:
        return torch.multinomial(self._weights, n, replacement=True, generator=generator)

    def sample_time(self, ids: torch.Tensor, truncate_time: float | None = None) -> torch.Tensor:
        phase = torch.rand(ids.shape, device=self.device)
        length = self._length[ids]
        if truncate_time is not None:
            length = torch.clamp(length - truncate_time, min=0.0)
        return phase * length

    def calc_motion_phase(self, ids: torch.Tensor, times: torch.Tensor) -> torch.Tensor:
        return self._phase_and_cycles(ids, times)[0]

    def calc_motion_frame(self, ids: torch.Tensor, times: torch.Tensor) -> MotionFrame:
        i0, i1, blend, cycles = self._frame_blend(ids, times)
        b = blend.unsqueeze(-1)
        root_pos = (1.0 - b) * _rows(self.root_pos, i0) + b * _rows(self.root_pos, i1)
        rots = tu.slerp(_rows(self._rots, i0), _rows(self._rots, i1), b.unsqueeze(-1))
        root_rot, joint_rot = rots[:, 0], rots[:, 1:]
        root_pos = root_pos + cycles.unsqueeze(-1) * _rows(self._wrap_delta, ids)
        vel, ang_vel, dof_vel = (_rows(t, i0) for t in (self.root_vel, self.root_ang_vel, self.dof_vel))
        return MotionFrame(root_pos, root_rot, vel, ang_vel, joint_rot, dof_vel)

    def joint_rot_to_dof(self, joint_rot: torch.Tensor) -> torch.Tensor:
        return self.char_model.rot_to_dof(joint_rot)

    def _phase_and_cycles(self, ids: torch.Tensor, times: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The phase in [0, 1] (t / length; a WRAP clip's fractional part) and the completed cycles (WRAP
        clips; 0 for the others)."""
        raw = times / _rows(self._length, ids).clamp_min(1e-8)
        wrap = _rows(self._loop_mode, ids) == LoopMode.WRAP
        cycles = torch.where(wrap, torch.floor(raw), 0.0)
        return (raw - cycles).clamp(0.0, 1.0), cycles

    def _frame_blend(
        self, ids: torch.Tensor, times: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """Global frame indices i0, i1, the blend between them and the completed cycles."""
        phase, cycles = self._phase_and_cycles(ids, times)
        nf = _rows(self._num_frames, ids)
        f = phase * (nf - 1).float()
        i0 = torch.clamp(f.long(), max=nf - 1)
        i1 = torch.minimum(i0 + 1, nf - 1)
        blend = (f - i0.float()).clamp(0.0, 1.0)
        start = _rows(self._start, ids)
        return start + i0, start + i1, blend, cycles


def _rows(table: torch.Tensor, ids: torch.Tensor) -> torch.Tensor:
    """table[ids]; for a 1-D ids as `index_select`, several times faster than advanced indexing on the CPU."""
    return table.index_select(0, ids) if ids.dim() == 1 else table[ids]
