"""Step-size control: skrl's KL-adaptive learning rate (``agent.lr_schedule=kl_adaptive``).

After each epoch of minibatch updates the PPO learning rate follows that epoch's mean
approximate KL between the policy that collected the rollout and the current one, measured on
each minibatch before its step: divided by 1.5 when the KL is above twice ``agent.kl_target``,
multiplied by 1.5 when it is below half of it, kept within [1e-6, 1e-2]. Per epoch and with
skrl's KL estimate (``kl_k3``), as skrl (the library the authors' agent is built on) does.
"""

from __future__ import annotations

import torch

LR_FACTOR = 1.5
KL_FACTOR = 2.0
LR_BOUNDS = (1e-6, 1e-2)


def kl_k3(kl_approx: float, mean_ratio: float) -> float:
    """skrl's KL estimate mean((r - 1) - log r) over a minibatch, r = pi_new / pi_old, from
    ``ClipPPOLoss``'s ``kl_approx`` = mean(-log r) and ``mean_ratio`` = mean(r).

    Never negative and less noisy than ``kl_approx`` alone, which a minibatch can make negative
    (and so raise the rate of a policy that moved).
    """
    return mean_ratio - 1.0 + kl_approx


def kl_adaptive_lr(
    lr: float, kl: float, kl_target: float, factor: float = LR_FACTOR, bounds=LR_BOUNDS
) -> float:
    """The next learning rate: ``lr / factor`` (not below ``bounds[0]``) when ``kl > 2 * kl_target``,
    ``lr * factor`` (not above ``bounds[1]``) when ``kl < kl_target / 2``, else ``lr``."""
    if kl > KL_FACTOR * kl_target:
        return max(lr / factor, bounds[0])
    if kl < kl_target / KL_FACTOR:
        return min(lr * factor, bounds[1])
    return lr


class KLAdaptiveLR:
    """Sets ``optimizer``'s learning rate with :func:`kl_adaptive_lr`.

    The rate lives only in the optimiser's parameter groups, so the optimiser's state dict (in
    every checkpoint) saves it and loading that state dict restores it.
    """

    def __init__(self, optimizer: torch.optim.Optimizer, kl_target: float) -> None:
        if not kl_target > 0:
            raise ValueError(f"agent.kl_target must be > 0, got {kl_target}")
        self.optimizer = optimizer
        self.kl_target = float(kl_target)

    def step(self, kl: float) -> float:
        """Update the learning rate from an epoch's mean approximate KL; returns the new rate."""
        for group in self.optimizer.param_groups:
            group["lr"] = kl_adaptive_lr(group["lr"], kl, self.kl_target)
        return self.optimizer.param_groups[0]["lr"]
