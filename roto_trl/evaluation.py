"""Evaluation: whole episodes of a separate env with deterministic actions, from a fixed seed."""

from __future__ import annotations

import torch
from torchrl.envs import TransformedEnv
from torchrl.envs.utils import ExplorationType, set_exploration_type

from roto_trl.modules.agent import Agent


@torch.no_grad()
def evaluate(env: TransformedEnv, agent: Agent, seed: int) -> dict[str, float]:
    """Run one whole episode in every world of ``env`` (physically reset, seeded with ``seed``).

    Worlds whose episode ended keep stepping until all have ended; only each world's first
    episode counts. Returns the mean and std of the episode return and the mean of each episode
    metric at the episode's last step (``bounces``, ``rotations``, ``find_time_<tol>cm``, ...).
    """
    env.set_seed(seed)
    td = env.reset()
    n = env.batch_size[0]
    ep_return = torch.zeros(n, device=td.device)
    finished = torch.zeros(n, dtype=torch.bool, device=td.device)
    columns = env.base_env.metric_columns()
    final = torch.zeros(n, len(columns), device=td.device)
    keys = agent.obs_keys
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        for _ in range(env.base_env.max_episode_steps):
            td.set("action", agent.policy(td.select(*keys).clone())["action"])
            out = env.step(td)["next"]
            live = ~finished
            ep_return += out["reward"].squeeze(-1) * live
            ended = out["done"].squeeze(-1) & live
            if bool(ended.any()):
                values = torch.stack([out[key][:, i] for key, i, _ in columns], dim=-1)
                final[ended] = values[ended].float()
                finished |= ended
            if bool(finished.all()):
                break
            td = out
    result = {"return_mean": float(ep_return.mean()), "return_std": float(ep_return.std(correction=0))}
    for c, (_, _, name) in enumerate(columns):
        result[name] = float(final[:, c].mean())
    return result
