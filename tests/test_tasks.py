"""Task logic: the bounce and rotation counters (by hand, then in the simulator), falls, rewards."""

import pytest
import torch
from helpers import hold_pose

from roto_trl import make_env
from roto_trl.envs.baoding import TARGETS, complete_rotations, swap_targets
from roto_trl.envs.batched_mujoco import PhysicsReading
from roto_trl.envs.bounce import BALL_REST, count_bounces
from roto_trl.envs.robot_env import sensor_force


def run_bounce_detector(contacts: list[int]) -> tuple[list[bool], list[int]]:
    free = torch.zeros(1, dtype=torch.long)
    bounces, frees = [], []
    for c in contacts:
        bounced, free = count_bounces(torch.tensor([bool(c)]), free)
        bounces.append(bool(bounced))
        frees.append(int(free))
    return bounces, frees


def test_sensor_force_is_the_largest_magnitude_over_substeps_worked_by_hand():
    # 2 worlds, 2 substeps, 2 sensors of 3 components each
    data = torch.zeros(2, 2, 6, dtype=torch.float64)
    data[0, 0, :3] = torch.tensor([3.0, 4.0, 0.0])  # 5 N
    data[0, 1, :3] = torch.tensor([0.0, 0.0, 1.0])  # 1 N
    data[1, 1, :3] = torch.tensor([1.0, 2.0, 2.0])  # 3 N
    data[1, 0, 3:] = torch.tensor([0.0, 0.0, -2.0])  # 2 N
    data[1, 1, 3:] = torch.tensor([0.0, 1e-3, 0.0])  # 1 mN
    empty = torch.zeros(2, 1)
    reading = PhysicsReading(qpos=empty, qvel=empty, sensordata=data, mocap_pos=empty)
    force = sensor_force(reading, slice(0, 6))
    assert force.dtype == torch.float32
    assert torch.equal(force, torch.tensor([[5.0, 0.0], [3.0, 2.0]]))
    assert torch.equal(sensor_force(reading, slice(3, 6)), torch.tensor([[0.0], [2.0]]))


def test_contact_after_five_free_steps_is_a_bounce():
    bounces, frees = run_bounce_detector([1, 0, 0, 0, 0, 0, 1])
    assert bounces == [False] * 6 + [True]
    assert frees == [0, 1, 2, 3, 4, 5, 0]


def test_contact_after_four_free_steps_is_not_a_bounce():
    bounces, _ = run_bounce_detector([1, 0, 0, 0, 0, 1, 1, 0, 0, 0, 0, 0, 0, 0, 1])
    assert bounces == [False] * 14 + [True]


def test_two_swaps_make_one_rotation():
    near, far = torch.tensor([0.005]), torch.tensor([0.05])
    phase = torch.zeros(1, dtype=torch.long)
    swapped, phase = swap_targets(near, far, phase)  # one ball there, the other not: no swap
    assert not bool(swapped) and int(complete_rotations(phase)) == 0
    swapped, phase = swap_targets(near, near, phase)
    assert bool(swapped) and int(phase) == 1 and int(complete_rotations(phase)) == 0
    swapped, phase = swap_targets(near, near, phase)
    assert int(phase) == 2 and int(complete_rotations(phase)) == 1
    assert complete_rotations(torch.tensor([0, 1, 2, 3, 4, 5])).tolist() == [0, 0, 1, 1, 2, 2]


def place(env, **bodies):
    """Reset every env with the named free bodies at the given positions (hand in default pose)."""
    env.reset()
    state = env.base_env.get_state()
    m = env.base_env.mj_model
    for name, pos in bodies.items():
        adr = m.jnt_qposadr[m.joint(name).id]
        state["qpos"][:, adr : adr + 3] = torch.tensor(pos, dtype=torch.float64)
        state["qpos"][:, adr + 3 : adr + 7] = torch.tensor([1.0, 0, 0, 0], dtype=torch.float64)
    return env.reset(qpos=state["qpos"])


def test_a_dropped_ball_bounces_once_in_the_simulator():
    env = make_env("bounce", 1, hand_reset_noise=0.0)
    td = place(env, ball=(BALL_REST[0], BALL_REST[1], BALL_REST[2] + 0.12))
    rewards = []
    for _ in range(40):
        td = hold_pose(env, 1, td)
        rewards.append(td["reward_terms", "bounce"].item())
    assert td["bounces"].item() == 1.0
    assert sum(rewards) == pytest.approx(10.0)  # one bounce, scaled by 10
    assert not bool(td["done"].any())
    env.close()


def test_bounce_terminates_with_penalty_when_the_ball_falls():
    env = make_env("bounce", 1, hand_reset_noise=0.0)
    td = place(env, ball=(0.3, 0.0, 0.3))  # 32 cm from the centre
    td = env.step(td.set("action", env.base_env.default_pose_action()[None]))["next"]
    assert bool(td["terminated"].all()) and bool(td["done"].all())
    assert td["reward_terms", "fall"].item() == pytest.approx(-10.0)
    env.close()


def test_air_reward_grows_with_steps_since_contact():
    env = make_env("bounce", 1, hand_reset_noise=0.0)
    td = place(env, ball=(BALL_REST[0], BALL_REST[1], BALL_REST[2] + 0.15))
    air = []
    for _ in range(4):
        td = hold_pose(env, 1, td)
        air.append(td["reward_terms", "air"].item())
    assert air == pytest.approx([0.01, 0.02, 0.03, 0.04])  # 0.01 x steps since contact
    env.close()


def test_balls_on_their_targets_swap_and_two_swaps_count_one_rotation():
    env = make_env("baoding", 1, hand_reset_noise=0.0)
    a, b = TARGETS
    td = place(env, ball_a=b, ball_b=a)  # each ball on the other's start: first swap
    td = hold_pose(env, 1, td)
    assert td["reward_terms", "rotation"].item() == pytest.approx(10.0)
    assert td["rotations"].item() == 0.0
    td = place(env, ball_a=a, ball_b=b)  # a new episode: counters restart
    assert td["rotations"].item() == 0.0
    base = env.base_env
    base._swaps[:] = 1  # one swap done: the targets point back to the start
    td = hold_pose(env, 1, td)
    assert td["rotations"].item() == 1.0
    env.close()


def test_baoding_terminates_when_the_balls_separate():
    env = make_env("baoding", 1, hand_reset_noise=0.0)
    td = place(env, ball_b=(0.2, -0.07, 0.32))
    td = hold_pose(env, 1, td)
    assert bool(td["terminated"].all())
    assert td["reward_terms", "fall"].item() == pytest.approx(-10.0)
    env.close()


def test_reward_is_the_sum_of_scaled_terms_and_scales_are_configurable():
    env = make_env("baoding", 2, reward_scales={"dist_a": 0.0, "rotation": 3.0})
    td = hold_pose(env, 3)
    terms = td["reward_terms"]
    assert torch.allclose(td["reward"], sum(terms.values()))
    assert bool((terms["dist_a"] == 0).all()) and bool((terms["dist_b"] > 0).all())
    env.close()
