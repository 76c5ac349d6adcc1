"""Multi-process helpers over `torch.distributed`, as the reference's `mp_util`.

One OS process per device; `init(rank, num_procs, device, port)` joins the process group (gloo on
CPU, NCCL on CUDA) at localhost:port, or, with port None, through env:// (MASTER_ADDR / MASTER_PORT as
torchrun sets them). With a single process no group is created and every collective is the identity,
so agents call these helpers unconditionally.

Collectives accept tensors or python scalars; scalars travel as a tensor on the process device and
come back as the same python type (an int stays an int).
"""

from __future__ import annotations

import os
import sys
from typing import TypeVar

import torch
import torch.distributed as dist

from mimickit.util import ranks

# The process's rank, count and device are kept in util.ranks (the motion library, below learning, reads
# them); these are the reference's names for them.
from mimickit.util.ranks import enable_mp as enable_mp
from mimickit.util.ranks import get_device as get_device
from mimickit.util.ranks import get_num_procs as get_num_procs
from mimickit.util.ranks import get_proc_rank as get_proc_rank
from mimickit.util.ranks import is_root_proc as is_root_proc

Scalar = TypeVar("Scalar", int, float, torch.Tensor)


def init(rank: int, num_procs: int, device: torch.device | str, master_port: int | None) -> None:
    """Join the process group of `num_procs` processes as `rank` (no group when `num_procs` is 1), at
    localhost:`master_port`, or with `master_port` None at the environment's MASTER_ADDR:MASTER_PORT."""
    ranks.set_proc(rank, num_procs, device)
    if num_procs <= 1:
        return
    if master_port is not None:
        os.environ["MASTER_ADDR"] = "localhost"
        os.environ["MASTER_PORT"] = str(master_port)
    device = get_device()
    backend = "nccl" if device.type == "cuda" and sys.platform != "win32" else "gloo"
    if device.type == "cuda":
        torch.cuda.set_device(device)
    dist.init_process_group(backend, init_method="env://", rank=rank, world_size=num_procs)


def shutdown(synchronize: bool = True) -> None:
    """Leave the process group (no-op for a single process). With `synchronize`, first wait until every
    process got here: gloo aborts a process (SIGABRT) that tears its group down while a peer still
    talks to it, and so does an interpreter exiting with the group alive. Without it (this process
    failed, its peers may never arrive) the group is torn down at once."""
    if enable_mp() and dist.is_initialized():
        if synchronize:
            dist.barrier()
        dist.destroy_process_group()
    ranks.set_proc(0, 1, get_device())


def broadcast(x: torch.Tensor) -> torch.Tensor:
    """A copy of rank 0's `x` on every process."""
    out = x.detach().clone()
    if enable_mp():
        dist.broadcast(out, src=0)
    return out


def broadcast_int(x: int) -> int:
    """Rank 0's `x` on every process (e.g. a seed only rank 0 drew)."""
    if not enable_mp():
        return x
    t = torch.tensor([x], dtype=torch.int64, device=get_device())
    dist.broadcast(t, src=0)
    return int(t.item())


def reduce_sum(x: Scalar) -> Scalar:
    return _reduce(x, dist.ReduceOp.SUM)


def reduce_prod(x: Scalar) -> Scalar:
    return _reduce(x, dist.ReduceOp.PRODUCT)


def reduce_min(x: Scalar) -> Scalar:
    return _reduce(x, dist.ReduceOp.MIN)


def reduce_max(x: Scalar) -> Scalar:
    return _reduce(x, dist.ReduceOp.MAX)


def reduce_mean(x: Scalar) -> Scalar:
    total = reduce_sum(x)
    if isinstance(total, int):
        return total // get_num_procs() if enable_mp() else total
    return total / get_num_procs()


def reduce_inplace_sum(x: torch.Tensor) -> None:
    if enable_mp():
        dist.all_reduce(x, op=dist.ReduceOp.SUM)


def reduce_inplace_mean(x: torch.Tensor) -> None:
    if enable_mp():
        dist.all_reduce(x, op=dist.ReduceOp.SUM)
        x /= get_num_procs()


def reduce_inplace_min(x: torch.Tensor) -> None:
    if enable_mp():
        dist.all_reduce(x, op=dist.ReduceOp.MIN)


def reduce_inplace_max(x: torch.Tensor) -> None:
    if enable_mp():
        dist.all_reduce(x, op=dist.ReduceOp.MAX)


def calc_mean_std(x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Mean and std of `x` [n] over all processes.

    As the reference: the average of per-process means and the square root of the average of
    per-process (unbiased) variances, not the exact pooled variance: kept, so advantages are normalised as there
    (docs/architecture.md, *Faithfulness to the reference*).
    Returns two 0-d tensors.
    """
    mean = x.mean()
    var = x.var() if x.numel() > 1 else torch.zeros_like(mean)
    if enable_mp():
        stats = torch.stack([mean, var])
        reduce_inplace_mean(stats)
        mean, var = stats[0], stats[1]
    return mean, var.sqrt()


def _reduce(x: Scalar, op: dist.ReduceOp) -> Scalar:
    if not enable_mp():
        return x.clone() if isinstance(x, torch.Tensor) else x
    if isinstance(x, torch.Tensor):
        out = x.detach().clone()
        dist.all_reduce(out, op=op)
        return out
    dtype = torch.int64 if isinstance(x, (int, bool)) else torch.float64
    t = torch.tensor([x], dtype=dtype, device=get_device())
    dist.all_reduce(t, op=op)
    return type(x)(t.item()) if not isinstance(x, bool) else int(t.item())
