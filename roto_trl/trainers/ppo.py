"""One PPO iteration on a collected rollout: advantages, the minibatch updates, rollout statistics."""

from __future__ import annotations

import torch
from tensordict import TensorDictBase

from roto_trl.modules.agent import Agent
from roto_trl.trainers.errors import NonFiniteError


@torch.no_grad()
def estimate_advantages(batch: TensorDictBase, agent: Agent, advantage) -> None:
    """Write ``advantage`` and normalised ``value_target`` / ``state_value`` into ``batch`` [N, R].

    Values of the rollout's observations come from the latent ``z`` the policy wrote while
    acting (same parameters, no second encoder pass); the next observation's value is the next
    step's, except after the last step and at episode ends, where the episode's final
    observation is encoded. GAE runs on the return scale; the value targets are then normalised
    with the running statistics, updated with this rollout's returns.
    """
    norm = agent.value_norm
    value = norm.denormalize(agent.value_head(batch["z"]))  # [N, R, 1]
    nxt = batch["next"]
    next_value = torch.cat([value[:, 1:], torch.zeros_like(value[:, :1])], dim=1)
    fresh = nxt["done"].clone()  # where next obs is not the following step's observation
    fresh[:, -1] = True
    where = fresh.squeeze(-1)
    next_value[where] = agent.raw_value(nxt[where])
    batch["state_value"] = value
    nxt["state_value"] = next_value
    advantage(batch)
    target = batch["value_target"]
    if not bool(torch.isfinite(target).all() and torch.isfinite(batch["advantage"]).all()):
        raise NonFiniteError("the return estimate is NaN or inf: check the reward scales and the env")
    norm.update(target)
    batch["value_target"] = norm.normalize(target)
    batch["state_value"] = norm.normalize(value)


def store_rollout(batch: TensorDictBase, agent: Agent, advantage, buffer, aux=None) -> None:
    """Estimate advantages of the rollout ``batch`` [N, R], put it in the (emptied) rollout
    buffer and, with an SSL objective, in the auxiliary memory."""
    estimate_advantages(batch, agent, advantage)
    buffer.empty()
    buffer.extend(batch.reshape(-1))
    if aux is not None:
        aux.memory.add(batch)


def ppo_update(
    cfg, buffer, agent, loss_fn, optimizer, params, aux=None
) -> tuple[dict[str, float], list[dict[str, float]]]:
    """``epochs`` passes of ``minibatches`` disjoint minibatches.

    Each minibatch: one PPO step (encoder + heads, gradient norm clipped), then, with an SSL
    objective ``aux``, one auxiliary step (encoder + auxiliary networks); the encoder gets each
    loss's gradient once.

    Returns:
        The mean PPO diagnostics (and mean auxiliary losses as ``aux/<name>``), and the numbers
        of every auxiliary step.
    """
    sums: dict[str, float] = {}
    aux_rows: list[dict[str, float]] = []
    steps = 0
    for _ in range(cfg.agent.epochs):
        for _ in range(cfg.agent.minibatches):
            minibatch = agent.encode(buffer.sample())
            losses = loss_fn(minibatch)
            total = losses["loss_objective"] + losses["loss_critic"] + losses["loss_entropy"]
            optimizer.zero_grad(set_to_none=True)
            total.backward()
            grad_norm = torch.nn.utils.clip_grad_norm_(params, cfg.agent.max_grad_norm)
            if not bool(torch.isfinite(total) and torch.isfinite(grad_norm)):
                bad = [k for k, v in losses.items() if k.startswith("loss_") and not torch.isfinite(v).all()]
                raise NonFiniteError(f"non-finite PPO loss {bad or ['gradient']}; try a smaller agent.lr")
            optimizer.step()
            steps += 1
            diag = {k: float(v.detach().mean()) for k, v in losses.items()}
            diag["grad_norm"] = float(grad_norm)
            aux_stats = aux.step() if aux is not None else None
            if aux_stats is not None:
                aux_rows.append(aux_stats)
                diag.update({f"aux/{k}": v for k, v in aux_stats.items() if "loss" in k})
            for k, v in diag.items():
                sums[k] = sums.get(k, 0.0) + v
    if not all(bool(torch.isfinite(p).all()) for p in params):
        raise NonFiniteError("a parameter became NaN or inf after the update; try a smaller agent.lr")
    return {k: v / steps for k, v in sums.items()}, aux_rows


def rollout_stats(batch: TensorDictBase, ep_return: torch.Tensor, columns) -> dict[str, float]:
    """Per-step reward terms and the return and metrics of episodes that ended in ``batch``.

    ``ep_return`` [N] carries each world's running return across rollouts (updated in place).
    """
    nxt = batch["next"]
    reward = nxt["reward"].squeeze(-1)  # [N, R]
    done = nxt["done"].squeeze(-1)
    stats = {"reward": float(reward.mean())}
    for term, value in nxt["reward_terms"].items():
        stats[f"reward/{term}"] = float(value.mean())
    returns = []
    for t in range(reward.shape[1]):
        ep_return += reward[:, t]
        ended = done[:, t]
        if bool(ended.any()):
            returns.append(ep_return[ended].clone())
            ep_return[ended] = 0.0
    if returns:
        ended_returns = torch.cat(returns)
        stats["episode_return"] = float(ended_returns.mean())
        stats["episodes"] = float(ended_returns.numel())
        for key, i, name in columns:
            stats[f"episode/{name}"] = float(nxt[key][..., i][done].float().mean())
    return stats
