"""Physics you can trust: resting balls settle, dropped and flicked balls do not tunnel, the balls
have the paper's masses and sizes, and a ball on the palm lights the palm sensor and no other."""

import mujoco
import numpy as np
import pytest
import torch
from helpers import hold_pose
from test_tasks import place

from roto_trl import make_env
from roto_trl.envs.baoding import TARGETS
from roto_trl.envs.bounce import BALL_REST
from roto_trl.envs.shadow_hand import SENSOR_LINKS

BALLS = {"bounce": ("ball",), "baoding": ("ball_a", "ball_b")}
PALM_TOP = 0.312  # world z of the palm's upper face with the wrist at zero (m)
PALM_CENTRE_XY = (-0.011, -0.038)


def ball_penetration(env) -> float:
    """Deepest penetration (m, >= 0) of any contact involving a ball, over all envs."""
    base = env.base_env
    m = base.mj_model
    d = mujoco.MjData(m)
    balls = {m.geom(name).id for name in BALLS["bounce" if m.nq == 31 else "baoding"]}
    deepest = 0.0
    for state in base._state:
        mujoco.mj_setState(m, d, state, mujoco.mjtState.mjSTATE_FULLPHYSICS)
        mujoco.mj_forward(m, d)
        for c in d.contact[: d.ncon]:
            if c.geom1 in balls or c.geom2 in balls:
                deepest = max(deepest, -float(c.dist))
    return deepest


def ball_positions(env, task) -> torch.Tensor:
    m, qpos = env.base_env.mj_model, env.base_env.get_state()["qpos"]
    adr = [m.jnt_qposadr[m.joint(b).id] for b in BALLS[task]]
    return torch.stack([qpos[:, a : a + 3] for a in adr], dim=1)  # [N, balls, 3]


@pytest.mark.parametrize("task", ["bounce", "baoding"])
def test_balls_placed_in_the_palm_settle_and_stay(task):
    env = make_env(task, 4, seed=0, hand_reset_noise=0.0)  # balls randomised, hand in its pose
    td = hold_pose(env, 90)  # 1.5 s to settle
    assert not bool(td["done"].any()), "a ball fell out of the default pose"
    start = ball_positions(env, task)
    deepest = 0.0
    for _ in range(6):
        td = hold_pose(env, 10, td)
        deepest = max(deepest, ball_penetration(env))
    drift = (ball_positions(env, task) - start).norm(dim=-1).max().item()
    speed = env.base_env.get_state()["qvel"][:, 24:].abs().max().item()
    assert drift < 1e-3, f"balls crept {drift * 1e3:.2f} mm over the next second"
    assert speed < 5e-3, f"balls still move at {speed:.4f} m/s (jitter)"
    assert deepest < 2e-3, f"penetration {deepest * 1e3:.2f} mm"
    env.close()


def test_a_ball_dropped_on_the_palm_does_not_tunnel():
    env = make_env("bounce", 1, hand_reset_noise=0.0)
    # from 22 cm above its rest point, just inside the 24 cm fall radius: ~2 m/s at impact
    td = place(env, ball=(BALL_REST[0], BALL_REST[1], BALL_REST[2] + 0.22))
    lowest, deepest = 1.0, 0.0
    for _ in range(60):
        td = hold_pose(env, 1, td)
        lowest = min(lowest, ball_positions(env, "bounce")[0, 0, 2].item())
        deepest = max(deepest, ball_penetration(env))
    assert not bool(td["done"].any())
    assert lowest > BALL_REST[2] - 0.01, "the ball went through the hand"
    assert deepest < 5e-3, f"penetration {deepest * 1e3:.2f} mm at impact"
    env.close()


def test_balls_do_not_tunnel_through_fingers_at_the_fastest_commanded_motions():
    env = make_env("baoding", 4, seed=1)
    td = hold_pose(env, 10)
    deepest = 0.0
    for step in range(90):  # bang-bang between the joint limits: the fastest a policy can move
        sign = 1.0 if (step // 3) % 2 else -1.0
        action = torch.full((4, 20), sign)
        action[:, :2] = 0.0  # keep the wrist level so the balls stay in reach of the fingers
        td = env.step(td.set("action", action))["next"]
        deepest = max(deepest, ball_penetration(env))
        pos = ball_positions(env, "baoding")
        over_palm = (pos[..., :2] - torch.tensor(PALM_CENTRE_XY)).norm(dim=-1) < 0.03
        assert not bool((over_palm & (pos[..., 2] < PALM_TOP)).any()), "a ball passed through the palm"
    assert deepest < 5e-3, f"penetration {deepest * 1e3:.2f} mm under the fastest motions"
    env.close()


def test_ball_masses_and_sizes_are_the_papers():
    for task, names, mass, diameter in [
        ("bounce", ["ball"], 0.030, 0.070),
        ("baoding", ["ball_a", "ball_b"], 0.055, 0.0381),
    ]:
        env = make_env(task, 1)
        m = env.base_env.mj_model
        for name in names:
            assert m.body_mass[m.body(name).id] == pytest.approx(mass)
            assert 2 * m.geom_size[m.geom(name).id][0] == pytest.approx(diameter)
        env.close()


def test_a_ball_resting_on_the_palm_lights_the_palm_sensor_and_no_other():
    env = make_env("baoding", 1, hand_reset_noise=0.0)
    base = env.base_env
    env.reset()
    state = base.get_state()
    state["qpos"][:, :24] = 0.0  # flat hand: fingers straight, thumb and wrist at zero
    m = base.mj_model
    a, b = (m.jnt_qposadr[m.joint(n).id] for n in ("ball_a", "ball_b"))
    state["qpos"][0, a : a + 7] = torch.tensor([0.0, -0.03, PALM_TOP + 0.01905 + 0.001, 1, 0, 0, 0])
    state["qpos"][0, b : b + 7] = torch.tensor([0.5, 0.5, 0.3, 1, 0, 0, 0])  # far away, falling
    td = env.reset(qpos=state["qpos"])
    flat = base.action_for_targets(np.zeros(20))[None]
    for _ in range(60):
        td = env.step(td.set("action", flat))["next"]
    lit = [SENSOR_LINKS[i] for i in td["tactile"][0, -len(SENSOR_LINKS) :].nonzero().flatten()]
    assert lit == ["palm"]
    # at rest the palm carries the ball's weight, 0.055 kg x 9.81 m/s^2
    assert td["contact_force"][0, SENSOR_LINKS.index("palm")].item() == pytest.approx(0.54, abs=0.02)
    env.close()


def test_targets_are_where_the_balls_rest():
    env = make_env("baoding", 2, seed=0, hand_reset_noise=0.0)
    hold_pose(env, 60)
    rest = ball_positions(env, "baoding")
    assert (rest - torch.tensor(TARGETS, dtype=torch.float64)).norm(dim=-1).max().item() < 0.02
    env.close()
