"""A run started by torchrun (or any launcher of the env:// convention): what the environment says.

`torchrun --nproc-per-node N -m mimickit.cli train ...` starts every process itself and tells each one
its place through environment variables: RANK (global), WORLD_SIZE, LOCAL_RANK and LOCAL_WORLD_SIZE
(this node's processes), MASTER_ADDR / MASTER_PORT (the rendezvous). `mimickit.run` then joins the
process group through env:// instead of spawning. Devices: `--devices` omitted means cpu for every
process, or cuda:LOCAL_RANK where torch sees GPUs; given, it names one device per process of the node
(LOCAL_WORLD_SIZE entries) and each process takes entry LOCAL_RANK. `--master_port` is refused: the
rendezvous is torchrun's (`--master-port`, `--rdzv-endpoint`).
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass

from mimickit.util.errors import MimicKitError

_MARKERS = ("RANK", "WORLD_SIZE", "LOCAL_RANK")
"""Any of these set means "launched by torchrun"; the rest must then be there too."""
_REQUIRED = ("RANK", "WORLD_SIZE", "LOCAL_RANK", "LOCAL_WORLD_SIZE", "MASTER_ADDR", "MASTER_PORT")


@dataclass(frozen=True)
class TorchrunEnv:
    rank: int
    world: int
    local_rank: int
    local_world: int
    master: str
    """MASTER_ADDR:MASTER_PORT, the rendezvous every process joined."""
    run_id: str | None
    """TORCHELASTIC_RUN_ID (torchrun's --rdzv-id; None from another env:// launcher)."""

    @property
    def nodes(self) -> int:
        return max(1, self.world // self.local_world)

    def record(self) -> dict[str, object]:
        """What args.json records about the launch."""
        return {
            "launcher": "torchrun",
            "world_size": self.world,
            "local_world_size": self.local_world,
            "nodes": self.nodes,
            "master": self.master,
            "run_id": self.run_id,
        }


def read_torchrun_env(environ: Mapping[str, str] | None = None) -> TorchrunEnv | None:
    """The torchrun environment of this process; None when it was not started that way. An incomplete
    or inconsistent one is one error naming the variable."""
    env = os.environ if environ is None else environ
    present = [k for k in _MARKERS if k in env]
    if not present:
        return None
    missing = [k for k in _REQUIRED if not env.get(k)]
    if missing:
        raise MimicKitError(
            f"{', '.join(present)} set but {', '.join(missing)} missing from the environment: start the run"
            f" with torchrun (which sets all of {', '.join(_REQUIRED)}), or unset {', '.join(present)}"
        )
    rank, world, local_rank, local_world, port = (
        _env_int(env, k) for k in ("RANK", "WORLD_SIZE", "LOCAL_RANK", "LOCAL_WORLD_SIZE", "MASTER_PORT")
    )
    for name, val, lo, hi in (
        ("WORLD_SIZE", world, 1, None),
        ("LOCAL_WORLD_SIZE", local_world, 1, world),
        ("RANK", rank, 0, world - 1),
        ("LOCAL_RANK", local_rank, 0, local_world - 1),
        ("MASTER_PORT", port, 1, 65_535),
    ):
        if val < lo or (hi is not None and val > hi):
            bound = f"between {lo} and {hi}" if hi is not None else f">= {lo}"
            raise MimicKitError(f"torchrun environment: {name}={val} must be {bound}")
    return TorchrunEnv(rank, world, local_rank, local_world, f"{env['MASTER_ADDR']}:{port}",
                       env.get("TORCHELASTIC_RUN_ID") or None)  # fmt: skip


def node_devices(devices: list[str], tenv: TorchrunEnv, cuda_count: int) -> list[str]:
    """The device of each process on this node (this process's is entry `tenv.local_rank`)."""
    n = tenv.local_world
    if devices:
        if len(devices) != n:
            raise MimicKitError(
                f"--devices {' '.join(devices)} names {len(devices)} device(s) but torchrun started {n}"
                f" process(es) on this node (LOCAL_WORLD_SIZE {n}): give {n}, one per process, or omit"
                " --devices (cpu, or cuda:LOCAL_RANK where there are GPUs)"
            )
        return list(devices)
    if cuda_count == 0:
        return ["cpu"] * n
    if n > cuda_count:
        raise MimicKitError(
            f"torchrun started {n} processes on this node but torch sees {cuda_count} GPU(s), one per"
            f" process needed: start at most {cuda_count} (--nproc-per-node), or give --devices ({n} entries)"
        )
    return [f"cuda:{i}" for i in range(n)]


def check_master_port(given: bool, tenv: TorchrunEnv) -> None:
    if given:
        raise MimicKitError(
            f"--master_port is not used under torchrun (its rendezvous is {tenv.master}): omit it and give"
            " torchrun --master-port or --rdzv-endpoint instead"
        )


def _env_int(env: Mapping[str, str], key: str) -> int:
    try:
        return int(env[key])
    except ValueError:
        raise MimicKitError(f"torchrun environment: {key}={env[key]!r} is not an integer") from None
