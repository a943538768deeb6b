"""Scripted policies and tiny training configs shared by the tests."""

import sys

import torch

from roto_trl.config import checked_config, compose_train
from roto_trl.utils.resources import TRAIN_SCRIPT

# the training command line, for tests that run it as a user would
TRAIN = [sys.executable, str(TRAIN_SCRIPT)]

# tiny and fast on top of +profile=smoke: short episodes, few gradient steps
TINY = [
    "+profile=smoke",
    "env.num_envs=8",
    "agent.rollout_len=16",
    "agent.minibatches=2",
    "agent.epochs=2",
    "total_frames=256",
    "eval.num_envs=2",
    "eval.every_frames=256",
    "+env.overrides.episode_steps=40",
    "progress=false",
    "torch_threads=1",
    "logger=csv",
]


# what ``import roto_trl`` sets for OpenMP where unset (roto_trl/__init__.py)
OPENMP_DEFAULTS = {"OMP_WAIT_POLICY": "PASSIVE", "GOMP_SPINCOUNT": "10000"}


def compose_cfg(overrides):
    """The training config of ``roto_trl/train.py`` with Hydra ``overrides``, typed and checked."""
    return checked_config(compose_train(overrides))


def hold_pose(env, steps: int, td=None):
    """Step ``env`` holding its default pose for ``steps`` steps; returns the last output."""
    base = env.base_env
    action = base.default_pose_action().expand(base.num_envs, -1).clone()
    td = env.reset() if td is None else td
    for _ in range(steps):
        td = env.step(td.set("action", action))["next"]
    return td


def random_actions(env, steps: int, seed: int = 0):
    """A fixed sequence of uniform random actions ``[steps, N, n_actions]``."""
    gen = torch.Generator().manual_seed(seed)
    base = env.base_env
    return torch.rand(steps, base.num_envs, base.n_actions, generator=gen) * 2 - 1


def franka_targets_for(base, ee_pos, fingers: float = 0.04, iters: int = 200):
    """Franka joint targets ``[9]`` that put the end-effector frame at ``ee_pos``, pointing down.

    Damped least squares on the env's model and its end-effector site (``mj_jacSite``) from the
    ready pose (position and the gripper's z axis straight down; the finger slides set to
    ``fingers`` metres each).
    """
    import mujoco
    import numpy as np

    from roto_trl.envs.find import TCP_SITE

    m = base.mj_model
    d = mujoco.MjData(m)
    site = m.site(TCP_SITE).id
    q = base._default_ctrl.copy()
    jp, jr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
    for _ in range(iters):
        d.qpos[:] = q
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        mujoco.mj_jacSite(m, d, jp, jr, site)
        z_axis = d.site_xmat[site].reshape(3, 3)[:, 2]
        err = np.concatenate([np.asarray(ee_pos) - d.site_xpos[site], np.cross(z_axis, [0, 0, -1])])
        jac = np.vstack([jp, jr])[:, :7]
        q[:7] += 0.5 * jac.T @ np.linalg.solve(jac @ jac.T + 1e-4 * np.eye(6), err)
        q[:7] = np.clip(q[:7], m.jnt_range[:7, 0], m.jnt_range[:7, 1])
    q[7:] = fingers
    return q


def drive(env, targets, steps: int, td=None):
    """Step ``env`` for ``steps`` steps holding the joint ``targets`` ``[nu]`` in every env."""
    base = env.base_env
    action = base.action_for_targets(targets).expand(base.num_envs, -1).clone()
    td = env.reset() if td is None else td
    for _ in range(steps):
        td = env.step(td.set("action", action))["next"]
    return td
