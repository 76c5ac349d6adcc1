"""Which process this is among a training's processes: its rank, their number and its device.

`learning.mp_util.init` sets them when it joins the process group and `mp_util.shutdown` resets them;
everything else only reads them. They live here, below every package, because the motion library
(`anim`, under `learning`) loads its rank's share of a dataset; `mp_util` keeps the reference's names
for them. A single process is rank 0 of 1 on the CPU until told otherwise.
"""

from __future__ import annotations

import torch

_num_procs = 1
_rank = 0
_device = torch.device("cpu")


def set_proc(rank: int, num_procs: int, device: torch.device | str) -> None:
    """This process is `rank` of `num_procs`, on `device` (for `mp_util` only)."""
    global _num_procs, _rank, _device
    _num_procs, _rank, _device = num_procs, rank, torch.device(device)


def get_num_procs() -> int:
    return _num_procs


def get_proc_rank() -> int:
    return _rank


def get_device() -> torch.device:
    return _device


def is_root_proc() -> bool:
    return _rank == 0


def enable_mp() -> bool:
    return _num_procs > 1
