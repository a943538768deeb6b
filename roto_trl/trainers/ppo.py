"""One PPO iteration on a collected rollout: advantages, the minibatch updates (``PPOUpdate``),
rollout statistics."""

from __future__ import annotations

import statistics

import torch
from tensordict import TensorDictBase
from tensordict.utils import NestedKey
from torchrl.objectives import LossModule

from roto_trl.modules.agent import LATENT_KEY, Agent
from roto_trl.modules.networks import hidden_precision
from roto_trl.trainers.errors import NonFiniteError
from roto_trl.trainers.lr_schedule import kl_k3


@torch.no_grad()
def estimate_advantages(batch: TensorDictBase, agent: Agent, advantage) -> None:
    """Write ``advantage`` and normalised ``value_target`` / ``state_value`` into ``batch`` [N, R].

    Values of the rollout's observations come from the latent ``z`` the policy wrote while
    acting (same parameters, no second encoder pass; a separate critic encodes them); the next
    observation's value is the next step's, except after the last step and at episode ends,
    where the episode's final observation is encoded. GAE runs on the return scale; the value
    targets are then normalised with the running statistics, updated with this rollout's returns.
    """
    norm = agent.value_norm
    value = norm.denormalize(agent.normalised_value(batch))  # [N, R, 1]
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


def minibatch_keys(agent: Agent, loss_fn: LossModule) -> list[NestedKey]:
    """The rollout entries a PPO minibatch reads (``minibatch_loss``): the observations the
    encoders take, ``loss_fn``'s action, log-probability, advantage, value target and old value.

    Why: the rollout holds about three times as much (the next observations, raw contact forces,
    the privileged state, reward terms, the distribution's parameters); keeping only these makes
    the buffer a third as large and its copy and gathers a little faster.
    """
    k = loss_fn.tensor_keys
    return [*agent.obs_keys, k.action, k.sample_log_prob, k.advantage, k.value_target, k.value]


PPO_TERMS = ("loss_objective", "loss_critic", "loss_entropy")
MEDIAN_OF = ("kl_approx", "kl_k3", "clip_fraction")  # per-minibatch numbers also logged as medians


def minibatch_loss(
    agent: Agent, loss_fn, minibatch: TensorDictBase, aux=None, aux_data: TensorDictBase | None = None
) -> tuple[torch.Tensor, TensorDictBase, dict[str, float] | None]:
    """The paper's Eq. 2 on one minibatch: L = L_PPO + c_aux L_aux.

    Args:
        minibatch: PPO's minibatch ``[M]`` from the rollout buffer.
        aux: the ``AuxiliaryUpdate``, or None; ``aux_data`` its minibatch (None: PPO alone).

    Returns:
        The total loss (scalar, one backward trains encoder, heads and auxiliary networks),
        PPO's loss outputs and the auxiliary numbers (None without an auxiliary minibatch).
    """
    losses = loss_fn(agent.encode(minibatch))
    total = sum(losses[k] for k in PPO_TERMS)
    aux_stats = None
    if aux is not None and aux_data is not None:
        aux_total, aux_stats = aux.objective(aux_data)
        total = total + aux_total
    return total, losses, aux_stats


class PPOUpdate:
    """One iteration's update of the agent on a collected rollout, with everything it needs:
    the PPO loss, the advantage estimator, the optimiser and its schedules, the rollout buffer
    and the self-supervised objective.

    Args:
        agent: the agent being trained.
        loss_fn: TorchRL's ``ClipPPOLoss`` over the agent's heads (``builders.make_ppo_loss``).
        advantage: GAE (``builders.make_advantage``).
        optimizer: the PPO optimiser over the agent's parameters.
        buffer: the rollout buffer, sampled in ``minibatches`` disjoint minibatches per epoch.
        epochs, minibatches, max_grad_norm: le, mb and the gradient-norm clip.
        lr_schedule: the KL-adaptive rate (``KLAdaptiveLR``), or None for a fixed rate.
        aux: the self-supervised objective (``AuxiliaryUpdate``), or None for PPO alone.
    """

    def __init__(
        self,
        agent: Agent,
        loss_fn: LossModule,
        advantage,
        optimizer: torch.optim.Optimizer,
        buffer,
        *,
        epochs: int,
        minibatches: int,
        max_grad_norm: float,
        lr_schedule=None,
        aux=None,
    ) -> None:
        self.agent, self.loss_fn, self.advantage = agent, loss_fn, advantage
        self.optimizer, self.buffer = optimizer, buffer
        self.epochs, self.minibatches, self.max_grad_norm = (
            int(epochs),
            int(minibatches),
            float(max_grad_norm),
        )
        self.lr_schedule, self.aux = lr_schedule, aux
        self.params = [p for group in optimizer.param_groups for p in group["params"]]
        self.keys = minibatch_keys(agent, loss_fn)  # what the buffer keeps of each rollout

    def store(self, batch: TensorDictBase) -> None:
        """Estimate the advantages of the rollout ``batch`` [N, R], put the entries a minibatch
        reads in the (emptied) rollout buffer and, with an SSL objective, the whole rollout in
        the auxiliary memory."""
        estimate_advantages(batch, self.agent, self.advantage)
        self.buffer.empty()
        self.buffer.extend(batch.select(*self.keys).reshape(-1))
        if self.aux is not None:
            self.aux.memory.add(batch)

    def step(self, minibatch: TensorDictBase, aux_data: TensorDictBase | None = None):
        """One update on ``minibatch`` (and ``aux_data``, an auxiliary minibatch or None): the
        backward of ``minibatch_loss``, the gradient norm clipped, the PPO optimiser's step and,
        with auxiliary data, the auxiliary one's. Under ``agent.precision=bfloat16`` every product
        of the backward runs in bfloat16 (``hidden_precision``).

        Returns ``ClipPPOLoss``'s output, the gradient norm before clipping and the auxiliary
        numbers (None without auxiliary data); a ``NonFiniteError`` for a non-finite loss or gradient.
        """
        total, losses, aux_stats = minibatch_loss(self.agent, self.loss_fn, minibatch, self.aux, aux_data)
        self.optimizer.zero_grad(set_to_none=True)
        if self.aux is not None:
            self.aux.zero_grad()
        with hidden_precision(self.agent.encoder.precision):  # the backward's products as the forward's
            total.backward()
        grad_norm = torch.nn.utils.clip_grad_norm_(self.params, self.max_grad_norm)
        if not bool(torch.isfinite(total) and torch.isfinite(grad_norm)):
            bad = [k for k, v in losses.items() if k.startswith("loss_") and not torch.isfinite(v).all()]
            raise NonFiniteError(f"non-finite PPO loss {bad or ['gradient']}; try a smaller agent.lr")
        self.optimizer.step()
        if aux_stats is not None:
            self.aux.step()
        return losses, grad_norm, aux_stats

    def update(self) -> tuple[dict[str, float], list[dict[str, float]]]:
        """``epochs`` passes of ``minibatches`` disjoint minibatches of the stored rollout.

        Each minibatch: one backward of L_PPO + c_aux L_aux (L_aux on the next of this epoch's
        auxiliary minibatches, ``aux.epoch``), then the optimisers' steps. With ``lr_schedule``
        the learning rate follows each epoch's mean ``kl_k3``.

        Returns:
            The mean diagnostics over minibatches (``ClipPPOLoss``'s, ``grad_norm``, ``kl_k3``:
            skrl's KL estimate, auxiliary losses as ``aux/<name>``), the medians of ``kl_approx``,
            ``kl_k3`` and ``clip_fraction`` (``<name>_median``), the learning rate after the
            update (``lr``), and the numbers of every auxiliary step.
        """
        rows: list[dict[str, float]] = []
        aux_rows: list[dict[str, float]] = []
        for _ in range(self.epochs):
            aux_batches = self.aux.epoch(self.minibatches) if self.aux is not None else iter(())
            epoch_kl = []
            for _ in range(self.minibatches):
                aux_data = next(aux_batches, None)  # before PPO's sample: the draws' order is the runs' seed
                losses, grad_norm, aux_stats = self.step(self.buffer.sample(), aux_data)
                diag = {k: float(v.detach().mean()) for k, v in losses.items()}
                diag["grad_norm"] = float(grad_norm)
                diag["kl_k3"] = kl_k3(diag["kl_approx"], diag["mean_ratio"])
                if aux_stats is not None:
                    aux_rows.append(aux_stats)
                    diag.update({f"aux/{k}": v for k, v in aux_stats.items()})
                rows.append(diag)
                epoch_kl.append(diag["kl_k3"])
            if self.lr_schedule is not None:
                self.lr_schedule.step(sum(epoch_kl) / len(epoch_kl))
        trained = [*self.params, *(self.aux.loss.auxiliary_parameters() if self.aux is not None else [])]
        if not all(bool(torch.isfinite(p).all()) for p in trained):
            raise NonFiniteError("a parameter became NaN or inf after the update; try a smaller agent.lr")
        keys = dict.fromkeys(k for row in rows for k in row)
        means = {k: sum(r[k] for r in rows if k in r) / sum(k in r for r in rows) for k in keys}
        for k in MEDIAN_OF:
            means[f"{k}_median"] = statistics.median(r[k] for r in rows)
        means["lr"] = float(self.optimizer.param_groups[0]["lr"])
        return means, aux_rows

    def __call__(self, batch: TensorDictBase) -> tuple[dict[str, float], list[dict[str, float]]]:
        """Store the rollout ``batch`` and update on it (``update``)."""
        self.store(batch)
        return self.update()

    def state_dict(self) -> dict:
        """What a checkpoint keeps of the update: the agent, the optimiser and the SSL objective."""
        state = {"agent": self.agent.state_dict(), "optimizer": self.optimizer.state_dict()}
        if self.aux is not None:
            state["aux"] = self.aux.state_dict()
        return state

    def load_state_dict(self, state: dict) -> None:
        self.agent.load_state_dict(state["agent"])
        self.optimizer.load_state_dict(state["optimizer"])
        if self.aux is not None:
            self.aux.load_state_dict(state["aux"])


SATURATED = 0.9  # |tanh mean| above this counts as saturated in ``mean_saturation``


def saturation(loc: torch.Tensor) -> float:
    """The fraction of entries of the policy's tanh mean ``loc`` with |loc| > ``SATURATED``."""
    return float((loc.abs() > SATURATED).float().mean())


RANK_STATES = 2048  # latent_rank's evenly spaced subsample of a rollout's states (10-20 ms)


def effective_rank(z: torch.Tensor) -> float:
    """Roy and Vetterli's (2007) effective rank of latents ``z`` ``[n, d]`` about their mean:
    exp of the entropy of the normalised singular values, from 1 (every state on one line) to d
    (variation spread evenly over all d directions); 0 when the latents do not vary at all (one
    state, or a constant encoder), where the entropy is undefined.

    Why it is logged: a policy encoder whose latents collapse onto few directions has been seen to
    come with a controller that falls back late in a run (docs/results_cpu.md).
    """
    centred = (z - z.mean(0)).double()  # float64: the Gram matrix squares the singular values
    singular = torch.linalg.eigvalsh(centred.T @ centred).clamp(min=0).sqrt()
    total = singular.sum()
    if not total > 0:
        return 0.0
    return float(torch.special.entr(singular / total).sum().exp())


def latent_rank(z: torch.Tensor) -> float:
    """:func:`effective_rank` of latents ``z`` ``[*B, d]`` on an evenly spaced subsample of at
    most ``RANK_STATES`` of them (training's ``latent_rank``, and evaluation's)."""
    z = z.reshape(-1, z.shape[-1])
    return effective_rank(z[:: max(1, z.shape[0] // RANK_STATES)])


def rollout_stats(
    batch: TensorDictBase, ep_return: torch.Tensor, columns, physical_metrics
) -> dict[str, float]:
    """Per-step reward terms, the return and metrics of episodes that ended in ``batch`` with the
    task's physical metrics of those (sampled-policy) episodes (``physical_metrics``, the task
    env's: ``episode/reached_3cm``, ``episode/bounces_per_10s``, ... beside the evaluations'), and the
    fraction of the policy mean's entries |loc| > 0.9 on the collected states (``mean_saturation``,
    read from the ``loc`` the policy wrote while acting: no extra forward pass), and the effective
    rank of the policy encoder's latents on up to ``RANK_STATES`` of those states (``latent_rank``,
    from the ``z`` written while acting).

    ``ep_return`` [N] carries each world's running return across rollouts (updated in place).
    """
    nxt = batch["next"]
    reward = nxt["reward"].squeeze(-1)  # [N, R]
    done = nxt["done"].squeeze(-1)
    stats = {"reward": float(reward.mean()), "mean_saturation": saturation(batch["loc"])}
    stats["latent_rank"] = latent_rank(batch[LATENT_KEY])
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
        final = {name: nxt[key][..., i][done] for key, i, name in columns}
        stats.update({f"episode/{name}": float(v.float().mean()) for name, v in final.items()})
        stats.update({f"episode/{name}": v for name, v in physical_metrics(final).items()})
    return stats
