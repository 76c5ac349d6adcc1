"""A/B rollouts: two checkpoints' policies stepped in lockstep from the same clip starts.

Each side is its own `Rollout` (its env from its own configs, its own policy). An episode pair starts
from one clip state: A's env samples it as usual (reference-state init), then B's env is told to start
from it (`mimickit.envs.viewable.TracksReference.start_next_resets_at`: the same clip, the same motion
time), so both characters begin in the same pose at the same moment of the reference. An episode that
ends first holds its last pose (no reward) until the other ends; then both start the next pair. Every
step appends one frame to each history, so frame i of A's history and frame i of B's are the same
moment: the player scrubs both with one timeline. A task's target (location, heading) is each env's own
draw, not shared.

Two sides pair when their envs are of one kind (the same env class), step at one control rate and
track the same clip(s): the same count, lengths and reference poses. Anything else is one
MimicKitError line naming the difference.
"""

from __future__ import annotations

import functools
from collections.abc import Callable

import torch

from mimickit.envs.viewable import TracksReference
from mimickit.util.errors import MimicKitError
from studio.scene.rollout import Rollout

CLIP_ATOL = 1e-4  # metres / radians: the reference poses of "the same clip" loaded by two envs


def check_pairable(a: Rollout, b: Rollout) -> None:
    """MimicKitError (one line) unless `a` and `b` can run as an A/B pair (see the module docstring)."""
    kind_a, kind_b = type(a.env).__name__, type(b.env).__name__
    if kind_a != kind_b:
        raise MimicKitError(
            f"A/B rollouts compare two checkpoints of one kind of env: A's env is {kind_a} "
            f"({a.source.env_config}), B's {kind_b} ({b.source.env_config})"
        )
    if not isinstance(a.env, TracksReference):
        raise MimicKitError(
            f"A/B rollouts start both sides from one clip state: {kind_a} ({a.source.env_config}) "
            "does not start its episodes from a clip"
        )
    if abs(a.dt - b.dt) > 1e-9:
        raise MimicKitError(f"A/B rollouts step together: A steps every {a.dt:.4f} s, B every {b.dt:.4f} s")
    if not _same_clips(a, b):
        raise MimicKitError(
            "A/B rollouts start both sides from one clip state, so both must track the same clip(s): "
            f"A's env ({a.source.env_config}) tracks {_describe(a)}, B's ({b.source.env_config}) {_describe(b)}"
        )


def _same_clips(a: Rollout, b: Rollout) -> bool:
    """The same clip count and lengths, and the same reference poses frame by frame (a copy of a clip under
    another name is the same clip; another clip of the same length is not)."""
    la, lb = _clip_lengths(a), _clip_lengths(b)
    if la.shape != lb.shape or not torch.allclose(la, lb, atol=CLIP_ATOL):
        return False
    lib_a, lib_b = a.env.motion_lib, b.env.motion_lib
    return all(
        x.shape == y.shape and torch.allclose(x, y, atol=CLIP_ATOL)
        for x, y in ((lib_a.root_pos, lib_b.root_pos), (lib_a.dof_pos, lib_b.dof_pos))
    )


def _clip_lengths(r: Rollout) -> torch.Tensor:
    lib = r.env.motion_lib
    return lib.get_motion_length(torch.arange(lib.num_motions())).float().cpu()


def _describe(r: Rollout) -> str:
    """The clip(s) a side tracks, for the refusal: file names, count and length."""
    lengths = _clip_lengths(r)
    names = sorted({f.rsplit("/", 1)[-1] for f in r.env.motion_lib.motion_files})
    shown = ", ".join(names[:3]) + (", ..." if len(names) > 3 else "")
    if len(lengths) == 1:
        return f"{shown} ({float(lengths[0]):.3f} s)"
    return f"{len(lengths)} clips ({shown}; {float(lengths.sum()):.3f} s in all)"


class RolloutPair:
    """A and B in lockstep (see the module docstring). Not thread-safe: the scene thread drives it once
    it is handed over. Both sides' `episode` counts the pairs (they start together)."""

    def __init__(self, a: Rollout, b: Rollout) -> None:
        check_pairable(a, b)
        self.a, self.b = a, b
        # Each side recorded its own (unshared) start when it was built: replace both by a shared one.
        self._start(Rollout.restart)

    @property
    def sides(self) -> tuple[Rollout, Rollout]:
        return self.a, self.b

    def reset(self, same_start: bool = False) -> None:
        """Both start a new episode from the clip state A's reset draws (`same_start`: A's last start)."""
        self._start(functools.partial(Rollout.reset, same_start=same_start), Rollout.reset)

    def step(self) -> None:
        """One control step of each (an ended one holds its pose); the next pair once both have ended."""
        for r in self.sides:
            if r.ended:
                r.hold()
            else:
                r.step(auto_reset=False)
        if self.a.ended and self.b.ended:
            self.reset()

    def reload_if_newer(self) -> bool:
        """Each side's newer checkpoint loaded (see `Rollout.reload_if_newer`); a new pair when either was."""
        reloaded = [r.reload_if_newer(reset=False) for r in self.sides]
        if any(reloaded):
            self.reset()
        return any(reloaded)

    def close(self) -> None:
        for r in self.sides:
            r.close()

    def _start(self, start: Callable[[Rollout], None], start_b: Callable[[Rollout], None] | None = None) -> None:
        """`start` A (its env draws the clip state), then B (by `start_b`, default `start`) from that same state."""
        start(self.a)
        env = self.a.env
        self.b.env.start_next_resets_at(env.get_motion_ids(), env.get_motion_time())
        (start_b or start)(self.b)
