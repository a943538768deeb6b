"""Step-size control: skrl's KL-adaptive learning rate (``agent.lr_schedule=kl_adaptive``).

After each epoch of minibatch updates the PPO learning rate follows that epoch's mean
approximate KL between the policy that collected the rollout and the current one, measured on
each minibatch before its step: divided by 1.5 when the KL is above twice ``agent.kl_target``,
multiplied by 1.5 when it is below half of it, kept within [1e-6, 1e-2]. Per epoch and with
skrl's KL estimate (``kl_k3``), as skrl (the library the authors' agent is built on) does.

``agent.anneal_step_size=true`` (off by default) shrinks the step size linearly to zero over
``total_frames``, as CleanRL's ``anneal_lr``: the fixed rate itself (``LinearDecayLR``), or with
the KL rule its target, so that the rule lowers the rate (with the rate annealed instead, the
rule would raise it back; a group outside the rule, the log-std's of ``log_std_fixed_lr`` or
``log_std_lr``, keeps its rate).
Both follow the frames trained, so a resumed run continues the ramp.
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


def remaining(value: float, progress: float) -> float:
    """``value`` x (1 - ``progress``), ``progress`` (the fraction of the frames trained) clamped
    to [0, 1]: the linear anneal to zero."""
    return value * (1.0 - min(max(progress, 0.0), 1.0))


class KLAdaptiveLR:
    """Sets ``optimizer``'s learning rate with :func:`kl_adaptive_lr`.

    The rate lives only in the optimiser's parameter groups, so the optimiser's state dict (in
    every checkpoint) saves it and loading that state dict restores it. With ``anneal`` the
    target follows ``set_progress``: ``kl_target`` x (1 - fraction of the frames trained).
    """

    def __init__(self, optimizer: torch.optim.Optimizer, kl_target: float, anneal: bool = False) -> None:
        if not kl_target > 0:
            raise ValueError(f"agent.kl_target must be > 0, got {kl_target}")
        self.optimizer = optimizer
        self.initial_kl_target = float(kl_target)
        self.kl_target = float(kl_target)
        self.anneal = anneal

    def set_progress(self, progress: float) -> None:
        """Before an update: ``progress`` is the fraction of ``total_frames`` trained."""
        if self.anneal:
            self.kl_target = remaining(self.initial_kl_target, progress)

    def step(self, kl: float) -> float:
        """Update the learning rate from an epoch's mean approximate KL; returns the new rate."""
        for group in self.optimizer.param_groups:
            if group.get("kl_adaptive", True):  # False: a group kept at its rate (the log-std's)
                group["lr"] = kl_adaptive_lr(group["lr"], kl, self.kl_target)
        return self.optimizer.param_groups[0]["lr"]


class LinearDecayLR:
    """The fixed rate annealed: each group's rate is its starting rate (``base_lr`` in the group,
    as ``make_optimizer`` records it; ``lr`` for groups without one) x (1 - fraction of the frames
    trained)."""

    def __init__(self, optimizer: torch.optim.Optimizer, lr: float) -> None:
        self.optimizer = optimizer
        self.initial_lr = float(lr)

    def set_progress(self, progress: float) -> None:
        for group in self.optimizer.param_groups:
            group["lr"] = remaining(group.get("base_lr", self.initial_lr), progress)

    def step(self, kl: float) -> float:
        """The rate does not follow the KL; returns the current rate."""
        return self.optimizer.param_groups[0]["lr"]
