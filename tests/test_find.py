"""Find on the Franka: the arm moves, the frame reaches the sphere, the pads feel only the sphere
and each other, the metrics."""

import math

import mujoco
import numpy as np
import pytest
import torch
from helpers import drive, franka_targets_for, hold_pose

from roto_trl import make_env
from roto_trl.envs.find import (
    PLATE_CENTRE,
    PLATE_HALF,
    PLATE_TOP,
    READY_POSE,
    SPHERE_LIFT,
    SPHERE_RADIUS,
    first_times,
)


@pytest.fixture
def env():
    env = make_env("find", 2, seed=0, joint_reset_deg=0.0)
    yield env
    env.close()


def ee_pos(td):
    return td["state"][:, 3:6]


def place_sphere(env, xyz):
    """Reset every env with the arm in its ready pose and the sphere centre at ``xyz``."""
    base = env.base_env
    state = base.get_state()
    qpos = torch.as_tensor(base._default_ctrl).expand(base.num_envs, -1).clone()
    mocap = torch.tensor(xyz, dtype=torch.float64).expand_as(state["mocap_pos"]).clone()
    return env.reset(qpos=qpos, qvel=torch.zeros_like(state["qvel"]), mocap_pos=mocap)


def contacts_of(base, env_index: int = 0) -> list[tuple[str, str]]:
    """The geom pairs in contact in world ``env_index``'s current state (named by geom or body)."""
    m, state = base.mj_model, base.get_state()
    d = mujoco.MjData(m)
    d.qpos[:] = state["qpos"][env_index].numpy()
    d.mocap_pos[:] = state["mocap_pos"][env_index].numpy()
    mujoco.mj_forward(m, d)

    def name(geom: int) -> str:
        return m.geom(geom).name or m.body(int(m.geom_bodyid[geom])).name

    return [(name(c.geom1), name(c.geom2)) for c in d.contact[: d.ncon]]


def test_ready_pose_points_down_over_the_plate(env):
    td = hold_pose(env, 30)
    target = torch.tensor([PLATE_CENTRE[0], PLATE_CENTRE[1], PLATE_TOP + 0.08])
    assert torch.allclose(ee_pos(td).double(), target.expand(2, -1).double(), atol=0.005)
    # the end-effector frame's z axis points straight down; ee_quat (w, x, y, z) sits in the
    # newest reading of prop just before the gripper width
    _, x, y, _ = td["prop"][0, -5:-1].double()
    z_axis_z = 1 - 2 * (x * x + y * y)  # third row, third column of the rotation matrix
    assert z_axis_z < -0.999


def test_a_fixed_action_moves_the_end_effector_by_centimetres(env):
    start = ee_pos(hold_pose(env, 5))
    base = env.base_env
    action = base.default_pose_action().expand(2, -1).clone()
    action[:, 0] += 0.2  # the base joint turns by 0.2 of its half range (about 33 degrees)
    td = env.reset()
    for _ in range(60):
        td = env.step(td.set("action", action))["next"]
    moved = torch.linalg.vector_norm(ee_pos(td) - start, dim=-1)
    assert bool((moved > 0.1).all()), moved


def test_pressing_on_the_plate_leaves_the_pads_off(env):
    # the sphere far in a corner, the gripper pushed 3 cm into the plate away from it
    td = place_sphere(env, (0.59, 0.09, PLATE_TOP + SPHERE_RADIUS + 0.0005))
    targets = franka_targets_for(env.base_env, (0.45, -0.05, PLATE_TOP - 0.02), fingers=0.04)
    td = drive(env, targets, 90, td=td)
    # the plate stopped the fingertips, about 1 cm below the frame: the frame stays that far up
    assert bool((ee_pos(td)[:, 2] > PLATE_TOP + 0.007).all()), ee_pos(td)
    assert bool((ee_pos(td)[:, 2] < PLATE_TOP + 0.02).all()), ee_pos(td)
    assert any("roto:plate" in pair for pair in contacts_of(env.base_env))
    assert float(td["contact_force"].abs().max()) == 0.0
    assert float(td["tactile"].max()) == 0.0


@pytest.mark.parametrize("xy", [(0.5, 0.0), (0.59, 0.09), (0.41, -0.09)])
def test_the_frame_reaches_the_sphere_centre_and_closing_there_fires_both_pads(env, xy):
    # every tolerance is reachable: inverse kinematics on the frame puts it on the sphere centre,
    # at the plate's centre and at two opposite corners
    sphere = (*xy, PLATE_TOP + SPHERE_RADIUS + SPHERE_LIFT)
    td = place_sphere(env, sphere)
    base = env.base_env
    td = drive(env, franka_targets_for(base, sphere, fingers=0.04), 90, td=td)
    assert bool((td["object_distance"] < 0.0005).all()), td["object_distance"]
    assert bool((td["find_time"] < 5.0).all()), td["find_time"]  # 3 cm, 1 cm and 0.05 cm reached
    # the open fingers straddle the sphere: nothing touches anything, the plate included
    assert contacts_of(base) == []
    assert float(td["contact_force"].max()) == 0.0
    td = drive(env, franka_targets_for(base, sphere, fingers=0.0), 60, td=td)
    assert bool((td["contact_force"] > 0.1).all()), td["contact_force"]
    assert bool((td["tactile"][:, -2:] == 1).all())
    width = td["prop"][:, -1]  # newest reading's last entry: gripper width
    assert bool((width > 2 * SPHERE_RADIUS - 0.004).all()), width
    mocap = base.get_state()["mocap_pos"][:, 0]
    assert torch.allclose(mocap, torch.tensor(sphere, dtype=torch.float64).expand(2, -1))
    assert bool((td["object_distance"] < 0.0005).all())
    assert not any("roto:plate" in pair for pair in contacts_of(base))


def test_closing_the_empty_gripper_fires_both_pads(env):
    base = env.base_env
    targets = base._default_ctrl.copy()
    targets[7:] = 0.0
    td = drive(env, targets, 60)
    assert bool((td["tactile"][:, -2:] == 1).all()), td["contact_force"]


def test_reset_places_the_sphere_on_the_plate_and_jitters_the_arm():
    env = make_env("find", 512, seed=3)
    base = env.base_env
    env.reset()
    state = base.get_state()
    sphere = state["mocap_pos"][:, 0]
    centre = torch.tensor(PLATE_CENTRE, dtype=torch.float64)
    assert bool(((sphere[:, :2] - centre).abs() <= PLATE_HALF).all())
    assert float((sphere[:, :2] - centre).abs().max()) > 0.9 * PLATE_HALF  # spread over the plate
    height = torch.full((512,), PLATE_TOP + SPHERE_RADIUS + 0.0005, dtype=torch.float64)
    assert torch.allclose(sphere[:, 2], height)
    ready = torch.tensor(list(READY_POSE.values()), dtype=torch.float64)
    # one physics substep after the reset: within 7 degrees plus what a substep moves
    offset = (state["qpos"][:, :7] - ready[:7]).abs()
    assert float(offset.max()) < math.radians(7.5) and float(offset.max()) > math.radians(6)
    env.close()


def test_first_times_keep_the_first_reach_of_each_tolerance():
    tol = torch.tensor([0.03, 0.01, 0.0005])
    times = torch.full((1, 3), float("inf"))
    times = first_times(torch.tensor([0.05]), times, torch.tensor([0.1]), tol)
    assert torch.isinf(times).all()
    times = first_times(torch.tensor([0.02]), times, torch.tensor([0.2]), tol)
    assert times[0, 0] == pytest.approx(0.2) and torch.isinf(times[0, 1:]).all()
    times = first_times(torch.tensor([0.005]), times, torch.tensor([0.3]), tol)
    times = first_times(torch.tensor([0.0]), times, torch.tensor([0.4]), tol)
    # the first time stays; later, closer steps do not overwrite it
    assert times[0].tolist() == pytest.approx([0.2, 0.3, 0.4])


def test_metrics_in_the_output_and_truncation_at_300(env):
    td = place_sphere(env, (0.5, 0.0, PLATE_TOP + SPHERE_RADIUS + 0.0005))
    d0 = float(td["object_distance"][0])
    assert d0 == pytest.approx(0.08 - SPHERE_RADIUS - SPHERE_LIFT, abs=0.006)
    assert td["find_time"].tolist() == [[5.0, 5.0, 5.0]] * 2  # not found yet: the episode length
    base = env.base_env
    action = base.default_pose_action().expand(2, -1).clone()
    for step in range(1, 301):
        out = env.step(td.set("action", action))["next"]
        assert bool(out["truncated"].all()) == (step == 300)
        assert not bool(out["terminated"].any())
        td = out
    dist = float(out["object_distance"][0])
    reward = float(out["reward"][0])
    assert reward == pytest.approx(1 - math.tanh(dist / 0.1), abs=1e-5)


def test_find_time_records_the_first_reach_in_seconds(env):
    sphere = (0.5, 0.0, PLATE_TOP + SPHERE_RADIUS + 0.0005)
    td = place_sphere(env, sphere)
    base = env.base_env
    # move the end-effector frame 2 cm above the sphere centre: within 3 cm, not within 1 cm
    targets = franka_targets_for(base, (sphere[0], sphere[1], sphere[2] + 0.02), fingers=0.04)
    action = base.action_for_targets(targets).expand(2, -1).clone()
    first_below_3cm = None
    for step in range(1, 121):
        td = env.step(td.set("action", action))["next"]
        if first_below_3cm is None and float(td["object_distance"][0]) < 0.03:
            first_below_3cm = step
    assert first_below_3cm is not None
    assert float(td["find_time"][0, 0]) == pytest.approx(first_below_3cm / 60, abs=1e-5)
    assert np.isclose(float(td["find_time"][0, 1]), 5.0)  # 1 cm: not reached
    assert np.isclose(float(td["find_time"][0, 2]), 5.0)  # 0.05 cm: not reached
