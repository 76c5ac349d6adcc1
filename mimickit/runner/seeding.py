"""The seed of a run: `--rand_seed`, or one drawn and recorded, and every generator (Python, NumPy, torch)
seeded from it, per process. `mimickit train|test`, `eval` and `video` seed the same way, so a seed
repeats an episode whichever of them plays it.
"""

from __future__ import annotations

import random
import secrets

import numpy as np
import torch

from mimickit.util.arg_parser import ArgParser


def draw_seed(args: ArgParser) -> tuple[int, str]:
    """(base seed, "rand_seed" | "drawn"): `--rand_seed`, or a fresh random one when it is absent or < 0."""
    seed = args.parse_int("rand_seed", -1)
    if seed >= 0:
        return seed, "rand_seed"
    return secrets.randbelow(2**31), "drawn"


def seed_everything(args: ArgParser, rank: int, base_seed: int | None = None) -> int:
    """Seed Python, NumPy and torch with `base_seed` (default: `draw_seed`) + 41 × rank; returns it."""
    seed = (draw_seed(args)[0] if base_seed is None else base_seed) + 41 * rank
    random.seed(seed)
    np.random.seed(seed % 2**32)
    torch.manual_seed(seed)
    return seed
