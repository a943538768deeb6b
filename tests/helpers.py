"""Scripted policies shared by the tests."""

import torch


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
