"""Actions -> joint targets: every part of [-1, 1] drives a joint somewhere, and the smoothing."""

import mujoco
import numpy as np
import pytest
import torch

from roto_trl import TASKS, make_env
from roto_trl.envs.robot_env import tendon_bounds

# The Shadow Hand's middle joints J1, each coupled to its distal joint J0 by the fixed tendon
# 0.00705 q_J0 - 0.00805 q_J1 in [-0.001, 0.001] with q_J0 in [0, 1.571]: q_J1 can reach at most
# (0.00705 * 1.571 + 0.001) / 0.00805 = 1.500068, below its joint limit and actuator range 1.571.
COUPLED_MIDDLE = ("FFJ1", "MFJ1", "RFJ1", "LFJ1")
COUPLED_TOP = 1.500068


def test_tendon_bounds_by_hand():
    # the coupling tendon above, solved for q_J1 (coefficient -0.00805, q_J0's part in [0, 0.01107555])
    low, high = tendon_bounds(-0.00805, 0.0, 0.00705 * 1.571, -0.001, 0.001)
    assert low == pytest.approx(-0.001 / 0.00805) and high == pytest.approx(COUPLED_TOP, abs=1e-6)
    # one joint alone, 0.01 q in [-0.007, 0.03]: q in [-0.7, 3.0]
    assert tendon_bounds(0.01, 0.0, 0.0, -0.007, 0.03) == pytest.approx((-0.7, 3.0))


@pytest.mark.parametrize("task", sorted(TASKS))
def test_both_ends_of_every_action_are_the_ends_of_its_joints_range(task):
    env = make_env(task, 2, action_ema=1.0)
    base = env.base_env
    m = base.mj_model
    joints = base._act_joint
    expected_low = m.jnt_range[joints, 0].copy()
    expected_high = m.jnt_range[joints, 1].copy()
    for a in range(m.nu):
        if base.joint_names[joints[a]].endswith(COUPLED_MIDDLE):
            expected_high[a] = COUPLED_TOP
    ends = base.targets_for_action(torch.tensor([[-1.0], [1.0]]).expand(2, m.nu))
    assert np.allclose(ends[0].numpy(), expected_low, atol=1e-6)
    assert np.allclose(ends[1].numpy(), expected_high, atol=1e-6)
    # linear in between: 0 is the middle of the range, so no part of [-1, 1] is clipped away
    middle = base.targets_for_action(torch.zeros(m.nu))
    assert torch.allclose(middle, (ends[0] + ends[1]) / 2)
    # MuJoCo applies the targets as they are: inside every actuator's control range
    ctrlrange = m.actuator_ctrlrange
    assert bool((ends[0].numpy() >= ctrlrange[:, 0]).all() and (ends[1].numpy() <= ctrlrange[:, 1]).all())
    # and the env hands the simulator exactly these targets (one env at -1, the other at +1)
    td = env.reset()
    env.step(td.set("action", torch.tensor([[-1.0], [1.0]]).expand(2, m.nu).float()))
    assert np.array_equal(base._ctrl[:, 0, : m.nu], ends.numpy())
    # an action outside [-1, 1] is clipped to the ends
    assert torch.equal(base.targets_for_action(torch.full((m.nu,), 50.0)), ends[1])
    env.close()


def test_franka_actions_reach_the_joint_limits_not_the_wider_actuator_range():
    # joint 6's actuator accepts [-3.75, 2.18], its joint only moves in [-1.66, 2.11]: mapped onto
    # the actuator range, actions below -0.29 all pushed the joint onto its limit and did nothing
    env = make_env("find", 1)
    base = env.base_env
    low, high = base.target_low[5].item(), base.target_high[5].item()
    assert (low, high) == pytest.approx((-1.6573, 2.1127))
    quarter = base.targets_for_action(torch.full((9,), -0.5))[5].item()
    assert quarter == pytest.approx(low + 0.25 * (high - low))
    # in the simulator the base joint, free to turn, ends on each of its limits at -1 and +1
    for end, limit in ((-1.0, -2.8973), (1.0, 2.8973)):
        action = base.default_pose_action().clone()
        action[0] = end
        td = env.reset()
        for _ in range(400):
            td = env.step(td.set("action", action[None]))["next"]
        assert base.get_state()["qpos"][0, 0].item() == pytest.approx(limit, abs=0.01)
    env.close()


def test_shadow_middle_joints_stop_where_their_coupling_tendon_does():
    # in the simulator a middle joint commanded to the top of its action range gets there, and
    # a command above it (the actuator's range goes to 1.571) moves it no further: that part of
    # the actuator range is dead, so actions do not map onto it
    env = make_env("bounce", 1, hand_reset_noise=0.0)
    base = env.base_env
    m = base.mj_model
    middle = [a for a in range(m.nu) if base.joint_names[base._act_joint[a]].endswith(COUPLED_MIDDLE)]
    assert len(middle) == 4
    reached = {}
    for top in (COUPLED_TOP, 1.571):
        d = mujoco.MjData(m)
        d.ctrl[:] = base._default_ctrl
        d.ctrl[middle] = top
        for _ in range(1000):
            mujoco.mj_step(m, d)
        reached[top] = d.qpos[base._act_joint[middle]].copy()
    assert np.allclose(reached[COUPLED_TOP], COUPLED_TOP, atol=0.015), reached
    assert np.allclose(reached[1.571], reached[COUPLED_TOP], atol=0.01), reached
    assert np.allclose(base.target_high[middle].numpy(), COUPLED_TOP, atol=1e-6)
    env.close()


@pytest.mark.parametrize("task, ema", [("find", 0.3), ("bounce", 1.0), ("baoding", 1.0)])
def test_targets_move_30_percent_per_step_on_find_and_all_the_way_on_the_shadow_tasks(task, ema):
    env = make_env(task, 1)
    base = env.base_env
    assert base.config.action_ema == ema
    td = env.reset()
    start = base._target.clone()
    top = base.target_high.expand_as(start)
    for step in range(1, 4):
        td = env.step(td.set("action", torch.ones(1, base.n_actions)))["next"]
        left = (1.0 - ema) ** step  # the fraction of the way still to go
        assert torch.allclose(base._target, top + left * (start - top))
        assert np.array_equal(base._ctrl[0, 0, : base.mj_model.nu], base._target[0].numpy())
    env.close()


def test_action_smoothing_is_an_override():
    env = make_env("bounce", 1, action_ema=0.25)
    base = env.base_env
    td = env.reset()
    start = base._target.clone()
    env.step(td.set("action", torch.ones(1, 20)))
    assert torch.allclose(base._target, 0.25 * base.target_high + 0.75 * start)
    env.close()
    env = make_env("find", 1, action_ema=1.0)
    assert env.base_env.config.action_ema == 1.0
    env.close()
