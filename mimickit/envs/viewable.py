"""What an env offers a viewer (the studio's live rollouts, its A/B pairs), declared rather than probed.

`Viewable`: every character env. The simulated character's object id and kinematic model, and the
object id of its reference character (the "ghost": a visual copy posed from the clip) when it shows one.

`TracksReference`: an env whose character tracks reference clips (DeepMimic and the envs built on it:
AMP, ASE, ADD, the AMP task envs). The clips it plays, the weight of each reward term it reports in
`info["reward_terms"]`, whether the reward tracks the reference's pose at every step, each body's position
error against the reference pose, and starting the next
episodes from given clip states (an A/B rollout starts both sides from one).

`ShowsTaskTarget`: an env with a task beside imitation (the AMP location and steering envs): what env 0's
task asks now, as a few numbers a viewer shows beside its marker.

A viewer asks `isinstance(env, TracksReference)` (and `ShowsTaskTarget`) for what it may show beyond the
character.
"""

from __future__ import annotations

import abc
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import torch

    from mimickit.anim.kin_char_model import KinCharModel
    from mimickit.anim.motion_lib import MotionLib


class Viewable(abc.ABC):
    """A character env a viewer can draw (see the module docstring)."""

    @property
    @abc.abstractmethod
    def char_model(self) -> KinCharModel:
        """The simulated character's kinematic model (its body names, in body order)."""

    @abc.abstractmethod
    def get_char_id(self) -> int:
        """The engine's object id of the simulated character."""

    @abc.abstractmethod
    def get_ref_char_id(self) -> int | None:
        """The object id of the reference character (the "ghost") viewers draw, None without one."""


class TracksReference(Viewable):
    """A character env that tracks reference clips (see the module docstring)."""

    @property
    @abc.abstractmethod
    def motion_lib(self) -> MotionLib:
        """The clips the env plays (`motion_files`: their resolved paths)."""

    @property
    @abc.abstractmethod
    def tracks_pose(self) -> bool:
        """Whether its reward pulls the character to the reference's pose at every step (DeepMimic, ADD):
        then each body's error against the ghost measures the policy. AMP, ASE and the AMP task envs only
        start episodes from clip states; their ghost plays on without the character following it."""

    @property
    @abc.abstractmethod
    def reward_weights(self) -> dict[str, float]:
        """{term: weight} of the unweighted terms each step reports in `info["reward_terms"]`."""

    @property
    @abc.abstractmethod
    def ref_char_offset(self) -> tuple[float, float, float]:
        """Where the reference character (the ghost) is drawn relative to the reference's own root
        position (metres): a viewer comparing the two paths takes it off the ghost's."""

    @abc.abstractmethod
    def body_pos_errors(self) -> torch.Tensor:
        """Each env's per-body position error [N, J] (metres) of its current state against its reference."""

    @abc.abstractmethod
    def get_motion_ids(self, env_ids: torch.Tensor | None = None) -> torch.Tensor:
        """The clip each env tracks [N] (or of `env_ids`)."""

    @abc.abstractmethod
    def get_motion_time(self, env_ids: torch.Tensor | None = None) -> torch.Tensor:
        """Each env's time in its clip [N] (or of `env_ids`), seconds."""

    @abc.abstractmethod
    def start_next_resets_at(self, motion_ids: torch.Tensor, times: torch.Tensor) -> None:
        """The next resets start from these clip states (motion ids [n], times [n]), before any sampled one."""


class ShowsTaskTarget(abc.ABC):
    """An env whose task has a target a viewer shows (see the module docstring)."""

    @abc.abstractmethod
    def task_target(self, env_id: int = 0) -> dict[str, float | bool | str]:
        """What env `env_id`'s task asks now and how far it is from it, in plain units: `kind` (the
        task's name) and the task's own keys (metres, m/s, degrees, booleans)."""
