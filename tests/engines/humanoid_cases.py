"""Humanoid states, targets and runs shared by the engine tests (28 DoFs: 8 ball joints as exp-maps, 4 hinges)."""

from __future__ import annotations

from collections.abc import Callable

import torch

from mimickit.engines.engine import Engine

# The humanoid's init pose (MIMICKIT_SPEC.md §5.2, the init_pose of data/envs/*humanoid*_env.yaml): the root
# at 0.882416 m, where the feet's boxes touch z = 0 (tests/anim/test_char_model.py checks that).
INIT_ROOT_POS = (0.0, 0.0, 0.882416)
HANGING = {"fix_root": True, "start_pos": (0.0, 0.0, 1.5)}  # create_obj kwargs: a fixed root in the air
# pd_explicit's explicit damping needs kd·dt/M < 2: 1920 Hz on the humanoid (its ankles reach 14.6 at 240 Hz)
PD_EXPLICIT_FREQ = 1920


def init_dof(n: int = 1) -> torch.Tensor:
    """[n, 28] the standing init pose (§5.2): shoulders' x at ±π/2 (arms down), everything else zero."""
    dof = torch.zeros(n, 28)
    dof[:, 6], dof[:, 10] = 1.5708, -1.5708
    return dof


def random_pd_state(gen: torch.Generator) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(dof_pos, dof_vel, PD target) [1, 28]: around the init pose, every ball joint rotated and moving."""
    dof = init_dof() + 0.3 * torch.randn(1, 28, generator=gen)
    return dof, torch.randn(1, 28, generator=gen), dof + 0.3 * torch.randn(1, 28, generator=gen)


def ball_target() -> torch.Tensor:
    """[1, 28] the init pose with all three exp-map components of the right shoulder and abdomen non-zero."""
    target = init_dof()
    target[0, 6:9] = torch.tensor([0.9, -0.4, 0.6])  # right shoulder
    target[0, 0:3] = torch.tensor([0.2, 0.3, -0.25])  # abdomen
    return target


def final_dofs_by_mode(make_engine: Callable[[str, int], Engine], target: torch.Tensor, steps: int) -> dict:
    """Drive a humanoid toward `target` for `steps` control steps with pos mode at 240 Hz and with pd_explicit
    at PD_EXPLICIT_FREQ; `make_engine(mode, sim_freq)` builds each. Returns {mode: final dof_pos [1, 28]}."""
    finals = {}
    for mode, freq in (("pos", 240), ("pd_explicit", PD_EXPLICIT_FREQ)):
        engine = make_engine(mode, freq)
        engine.set_cmd(0, target)
        for _ in range(steps):
            engine.step()
        finals[mode] = engine.get_dof_pos(0).clone()
    return finals


def push_standing(engine: Engine, force: tuple[float, float, float] = (400.0, 0.0, 0.0)) -> dict:
    """Two standing humanoids (envs 0 and 1, PD holding the init pose); env 0's pelvis (body 0) is pushed
    with `force` for 0.2 s, env 1 is the same run without the push. Returns the push's control steps,
    the pushes left right after it ended, and both roots' positions [2, 3] 0.5 s after it began."""
    engine.set_dof_pos(None, 0, init_dof(2))
    engine.set_cmd(0, init_dof(2))
    for _ in range(10):  # settle on the feet
        engine.step()
    steps = engine.apply_body_force(0, 0, 0, force, duration_s=0.2)
    acting = engine.get_body_forces()
    for _ in range(steps):
        engine.step()
    left = engine.get_body_forces()
    for _ in range(15 - steps):
        engine.step()
    return {"steps": steps, "acting": acting, "left": left, "root_pos": engine.get_root_pos(0).clone()}
