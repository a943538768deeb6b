"""Evaluation: whole episodes of a separate env with deterministic actions, from a fixed seed."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
from tensordict import TensorDictBase
from torchrl.envs import TransformedEnv
from torchrl.envs.utils import ExplorationType, set_exploration_type

from roto_trl.modules.agent import LATENT_KEY, Agent
from roto_trl.trainers.ppo import RANK_STATES, latent_rank


@dataclass
class Episodes:
    """One episode per world of an evaluation env.

    Attributes:
        returns: ``[E]`` undiscounted episode returns.
        lengths: ``[E]`` control steps of each episode.
        final: ``name -> [E]`` each episode metric (``bounces``, ``find_time_3cm``, ...) at the
            episode's last step.
        frames: RGB frames ``[H, W, 3]`` of world 0's episode, when asked for.
        latent_rank: the effective rank of the policy encoder's latent ``z`` on about
            ``RANK_STATES`` of the states the episodes visited (``ppo.latent_rank``).
    """

    returns: torch.Tensor
    lengths: torch.Tensor
    final: dict[str, torch.Tensor]
    frames: list[np.ndarray]
    latent_rank: float


@torch.no_grad()
def run_episodes(
    env: TransformedEnv,
    agent: Agent,
    seed: int,
    render: Callable[[], np.ndarray] | None = None,
    on_step: Callable[[TensorDictBase, TensorDictBase, torch.Tensor], None] | None = None,
    max_steps: int | None = None,
    stochastic: bool = False,
) -> Episodes:
    """Run one whole episode in every world of ``env`` (physically reset, seeded with ``seed``).

    Worlds whose episode ended keep stepping until all have ended; only each world's first
    episode counts.

    Args:
        render: called after the reset and after every step of world 0's episode (e.g.
            ``lambda: env.base_env.render(0)``); its frames are returned.
        on_step: called before each step with the env's output ``[E]`` (the observation the
            action answers), the policy's output ``[E]`` (encoder inputs, ``z``, ``action``) and
            ``live`` ``[E]`` bool (the world is still in its first episode).
        max_steps: stop after this many steps (default: the episode length).
        stochastic: act with samples of the policy's Gaussian (clipped by the env, as in
            training) instead of its mean.
    """
    env.set_seed(seed)
    td = env.reset()
    n = env.batch_size[0]
    returns = torch.zeros(n, device=td.device)
    lengths = torch.zeros(n, dtype=torch.long, device=td.device)
    finished = torch.zeros(n, dtype=torch.bool, device=td.device)
    columns = env.base_env.metric_columns()
    final = torch.zeros(n, len(columns), device=td.device)
    frames = [render()] if render is not None else []
    keys = agent.obs_keys
    steps = (
        env.base_env.max_episode_steps
        if max_steps is None
        else min(max_steps, env.base_env.max_episode_steps)
    )
    exploration = ExplorationType.RANDOM if stochastic else ExplorationType.DETERMINISTIC
    stride = max(1, n * steps // RANK_STATES)  # the steps whose latents latent_rank reads
    latents = []
    # the stochastic policy's samples come from ``seed`` and leave the caller's RNG where it was
    with torch.random.fork_rng(enabled=stochastic), set_exploration_type(exploration):
        if stochastic:
            torch.manual_seed(seed)
        for step in range(steps):
            live = ~finished
            decision = agent.policy(td.select(*keys).clone())
            if step % stride == 0:
                latents.append(decision[LATENT_KEY][live])
            if on_step is not None:
                on_step(td, decision, live)
            td.set("action", decision["action"])
            out = env.step(td)["next"]
            returns += out["reward"].squeeze(-1) * live
            lengths += live.long()
            if render is not None and bool(live[0]):
                frames.append(render())
            ended = out["done"].squeeze(-1) & live
            if bool(ended.any()):
                values = torch.stack([out[key][:, i] for key, i, _ in columns], dim=-1)
                final[ended] = values[ended].float()
                finished |= ended
            if bool(finished.all()):
                break
            td = out
    metrics = {name: final[:, c].cpu() for c, (_, _, name) in enumerate(columns)}
    return Episodes(returns.cpu(), lengths.cpu(), metrics, frames, latent_rank(torch.cat(latents).cpu()))


def evaluate(env: TransformedEnv, agent: Agent, seed: int) -> dict[str, float]:
    """:func:`run_episodes`, summarised: return mean and std, each episode metric's mean and the
    task's physical metrics (``physical_metrics``: Find's ``reached_<tol>``, ``bounces_per_10s``,
    ``rotations_per_10s``), so that ``eval.csv`` holds the results table's numbers at every
    evaluation (``analyse.py table``), and the encoder's ``latent_rank``."""
    episodes = run_episodes(env, agent, seed)
    result = {
        "return_mean": float(episodes.returns.mean()),
        "return_std": float(episodes.returns.std(correction=0)),
        "latent_rank": episodes.latent_rank,
    }
    result.update({name: float(v.mean()) for name, v in episodes.final.items()})
    result.update(env.base_env.physical_metrics(episodes.final))
    return result


def selection_key(result: dict[str, float] | None, headline: str) -> tuple[float, float]:
    """How a run ranks an evaluation ``result`` for its best checkpoint: the task's headline
    metric first (Find's fraction within 3 cm, bounces or rotations per 10 s), the return to
    break ties (32 Find episodes give the fraction in steps of 1/32, and an untrained policy
    scores 0 on every task); ``(-inf, -inf)`` for no evaluation yet."""
    if result is None:
        return (-math.inf, -math.inf)
    return (float(result[headline]), float(result["return_mean"]))
