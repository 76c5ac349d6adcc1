"""DeepMimicEnv.body_pos_errors on the real MuJoCo engine: zero at the reference state, a hand computation
from the engine's bodies and the reference's, a perturbed joint moving only the bodies below it, and the
mean over bodies being the paper's position error."""

import numpy as np
import torch

from mimickit.envs.deepmimic_rewards import body_pos_errors
from tests.envs.test_deepmimic_env import DEEPMIMIC, make


def descendants(char, j: int) -> set[int]:
    """The bodies strictly below body `j` in the kinematic tree."""
    below: set[int] = set()
    for b in range(char.get_num_joints()):  # parents come before their children
        p = char.get_parent_id(b)
        if p == j or p in below:
            below.add(b)
    return below


def test_zero_at_the_reference_state():
    env = make(DEEPMIMIC, num_envs=3)
    env.reset()
    err = env.body_pos_errors()
    assert err.shape == (3, env.char_model.get_num_joints())
    assert float(err.max()) < 1e-5


def test_a_perturbed_shoulder_moves_only_the_arm_below_it():
    env = make(DEEPMIMIC, num_envs=2)
    env.reset()
    char, c = env.char_model, env.get_char_id()
    j = char.get_body_id("right_upper_arm")
    dof = env.get_char_state()["dof_pos"].clone()
    start = char.get_joint_dof_idx(j)  # the shoulder: body j's own joint
    dof[0, start : start + char.get_joint_dof_dim(j)] += torch.tensor([0.0, 0.6, 0.0])
    env.engine.set_dof_pos(torch.tensor([0]), c, dof[0:1])
    err = env.body_pos_errors().numpy()

    # By hand: the engine's body positions against the reference's, root-relative, the root global.
    sim = env.engine.get_body_pos(c).numpy()
    ref = env.get_ref_state()["body_pos"].numpy()
    rel = np.linalg.norm((sim - sim[:, :1]) - (ref - ref[:, :1]), axis=-1)
    expected = np.concatenate([np.linalg.norm(sim[:, 0] - ref[:, 0], axis=-1)[:, None], rel[:, 1:]], axis=1)
    np.testing.assert_allclose(err, expected, atol=1e-6)

    moved = {b for b in range(char.get_num_joints()) if err[0, b] > 1e-3}
    assert moved == descendants(char, j) == {char.get_body_id("right_lower_arm"), char.get_body_id("right_hand")}
    assert err[0, char.get_body_id("right_hand")] > err[0, char.get_body_id("right_lower_arm")] > 0.05
    assert float(err[1].max()) < 1e-5  # the other env untouched


def test_mean_over_bodies_is_the_paper_position_error():
    env = make(DEEPMIMIC, num_envs=4)
    env.reset()
    for _ in range(8):  # zero actions: the character drifts from the reference
        env.step(torch.zeros(4, env.get_action_space().shape[0]))
    err = env.body_pos_errors()
    assert float(err.max()) > 0.01
    paper = env.score_state()["tracking"]["paper_pos_err_m"]
    torch.testing.assert_close(err.mean(-1), paper, atol=1e-6, rtol=1e-5)


def test_the_function_on_hand_made_states():
    root = torch.tensor([[0.0, 0.0, 1.0]])
    body = torch.tensor([[[0.0, 0.0, 1.0], [0.0, 0.0, 1.5], [0.3, 0.0, 1.0]]])
    shifted = {"root_pos": root + torch.tensor([0.2, 0.0, 0.0]), "body_pos": body + torch.tensor([0.2, 0.0, 0.0])}
    ref = {"root_pos": root, "body_pos": body}
    # A rigid shift: only the root's global error (0.2 m); the others are root-relative, 0.
    torch.testing.assert_close(body_pos_errors(shifted, ref), torch.tensor([[0.2, 0.0, 0.0]]))
    bent = {"root_pos": root, "body_pos": body.clone()}
    bent["body_pos"][0, 2] = torch.tensor([0.0, 0.3, 1.0])  # the third body swung 90° about the root
    torch.testing.assert_close(body_pos_errors(bent, ref), torch.tensor([[0.0, 0.0, 0.3 * 2**0.5]]))
