"""Task logic: the bounce and rotation counters (by hand, then in the simulator), falls, rewards."""

import math

import mujoco
import numpy as np
import pytest
import torch
from helpers import hold_pose

from roto_trl import make_env
from roto_trl.envs.baoding import TARGETS, complete_rotations, pair_angle, swap_targets, unwrapped_step
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
    near = torch.tensor([0.005])
    for rule in ("latched", "simultaneous"):
        phase, marks = torch.zeros(1, dtype=torch.long), torch.zeros(1, 2, dtype=torch.bool)
        swapped, phase, marks = swap_targets(near, near, phase, marks, rule)
        assert bool(swapped) and int(phase) == 1 and int(complete_rotations(phase)) == 0
        swapped, phase, marks = swap_targets(near, near, phase, marks, rule)
        assert int(phase) == 2 and int(complete_rotations(phase)) == 1
    assert complete_rotations(torch.tensor([0, 1, 2, 3, 4, 5])).tolist() == [0, 0, 1, 1, 2, 2]


def test_a_visit_one_ball_after_the_other_swaps_under_the_latched_rule_only():
    """Ball A reaches its target and leaves, then ball B reaches its own: the authors' latched rule
    pays the swap at B's arrival (and clears both marks), the paper's simultaneous rule never."""
    near, far = torch.tensor([0.005]), torch.tensor([0.05])
    visits = [(near, far), (far, far), (far, near)]  # A there; neither; B there
    for rule, paid in (("latched", [False, False, True]), ("simultaneous", [False, False, False])):
        phase, marks = torch.zeros(1, dtype=torch.long), torch.zeros(1, 2, dtype=torch.bool)
        swaps = []
        for dist_a, dist_b in visits:
            swapped, phase, marks = swap_targets(dist_a, dist_b, phase, marks, rule)
            swaps.append(bool(swapped))
        assert swaps == paid, rule
        assert not bool(marks.any())  # latched: cleared at the swap; simultaneous: never set
    marks = torch.zeros(1, 2, dtype=torch.bool)
    _, _, marks = swap_targets(near, far, torch.zeros(1, dtype=torch.long), marks)
    assert marks.tolist() == [[True, False]]  # A's mark is kept until B arrives


def test_turns_by_hand_once_around_either_way():
    """Ball B moved once around ball A in 12 steps about the normal z: +1 turn counter-clockwise
    (the angle unwrapped across +-pi), -1 the other way; an unset previous angle adds nothing."""
    normal = torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64)
    centre = torch.zeros(1, 3, dtype=torch.float64)
    for sign in (1.0, -1.0):
        previous, turned = (
            torch.full((1,), float("nan"), dtype=torch.float64),
            torch.zeros(1, dtype=torch.float64),
        )
        for k in range(13):
            phi = sign * 2 * math.pi * k / 12
            pos_b = torch.tensor([[math.cos(phi), math.sin(phi), 0.3]], dtype=torch.float64)
            angle = pair_angle(centre, pos_b, normal)
            turned += unwrapped_step(angle, previous)
            previous = angle
        assert float(turned) / (2 * math.pi) == pytest.approx(sign)


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
    base = env.base_env
    base._marks[:] = True  # left over from the episode: a new one must not start with them
    td = place(env, ball_a=a, ball_b=b)  # a new episode: counters, marks and targets restart
    assert td["rotations"].item() == 0.0 and not bool(base._marks.any()) and int(base._swaps) == 0
    base._swaps[:] = 1  # one swap done: the targets point back to the start
    td = hold_pose(env, 1, td)
    assert td["rotations"].item() == 1.0
    env.close()


@pytest.mark.parametrize("rule", ["latched", "simultaneous"])
def test_placed_balls_carried_once_around_read_one_turn_and_two_swaps(rule):
    """The env's own accounting on placed states: the pair carried once around the midpoint of the
    targets about the palm's normal in 24 steps, each ball passing the other's target on the way,
    reads +1 turn and two swaps (-1 turn the other way); then a new episode reads 0 again."""
    env = make_env("baoding", 1, hand_reset_noise=0.0, swap_rule=rule)
    base = env.base_env
    hold_pose(env, 1)
    m = base.mj_model
    a, b = (torch.tensor(t, dtype=torch.float64) for t in TARGETS)
    centre, half = (a + b) / 2, (b - a) / 2
    sensors = base._reading().sensordata[:, -1:].clone()  # the simulator's own palm reading
    normal = -sensors[0, 0, base._palm_y]
    for sign in (1.0, -1.0):
        base._on_reset_mask(np.array([0]))
        swaps = 0
        for k in range(25):
            phi = sign * 2 * math.pi * k / 24
            turn = rotation_about(normal, phi)
            qpos = torch.zeros(1, m.nq, dtype=torch.float64)
            for name, pos in (("ball_a", centre - turn @ half), ("ball_b", centre + turn @ half)):
                adr = int(m.jnt_qposadr[m.joint(name).id])
                qpos[0, adr : adr + 3] = pos
            reading = PhysicsReading(qpos=qpos, qvel=torch.zeros(1, m.nv), sensordata=sensors, mocap_pos=None)
            swaps += int(base._compute_reward(reading)["rotation"].item())
        assert float(base._turned[0]) / (2 * math.pi) == pytest.approx(sign)
        assert swaps == 2 and int(complete_rotations(base._swaps)) == 1
    env.close()


def test_the_palm_normal_points_up_out_of_the_palm_that_holds_the_balls():
    """The turns are measured about the palm's normal: in the default pose the palm faces up
    (within 15 degrees of the world's z), and its normal follows the wrist as the hand moves."""
    env = make_env("baoding", 1, hand_reset_noise=0.0)
    base = env.base_env
    hold_pose(env, 1)
    normal = -base._reading().sensordata[0, -1, base._palm_y]
    assert float(normal.norm()) == pytest.approx(1.0)
    assert float(normal[2]) > math.cos(math.radians(15))
    palm = base.mj_model.body("robot0:palm").id
    pose = base.default_pose_action()
    pose[:2] = -1.0  # both wrist joints to a limit: the palm tilts, and the normal with it
    td = env.reset()
    for _ in range(30):
        td = env.step(td.set("action", pose.unsqueeze(0)))["next"]
    tilted = -base._reading().sensordata[0, -1, base._palm_y]
    data = mujoco.MjData(base.mj_model)
    data.qpos[:] = base._reading().qpos[0].numpy()
    mujoco.mj_kinematics(base.mj_model, data)
    assert torch.allclose(tilted, -torch.from_numpy(data.xmat[palm].reshape(3, 3)[:, 1]), atol=1e-3)
    assert float(torch.dot(tilted, normal)) < math.cos(math.radians(20))
    env.close()


def rotation_about(axis: torch.Tensor, angle: float) -> torch.Tensor:
    """The 3 x 3 rotation by ``angle`` about the unit ``axis`` (Rodrigues)."""
    k = torch.tensor([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return torch.eye(3, dtype=torch.float64) + math.sin(angle) * k + (1 - math.cos(angle)) * k @ k


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
