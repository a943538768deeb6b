"""Running mean and variance of returns, to train the value head on a normalised scale."""

from __future__ import annotations

import torch
from torch import nn


def merge_moments(
    mean: torch.Tensor, var: torch.Tensor, count: torch.Tensor, batch: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Combine running (mean, var, count) with a batch of samples (Chan et al.'s parallel update).

    Args:
        mean, var, count: scalars of the samples seen so far (population variance).
        batch: new samples, any shape.

    Returns:
        The (mean, var, count) of all samples together.
    """
    b_mean = batch.mean()
    b_var = batch.var(correction=0)
    b_count = torch.tensor(float(batch.numel()), dtype=count.dtype, device=count.device)
    total = count + b_count
    delta = b_mean - mean
    new_mean = mean + delta * b_count / total
    m2 = var * count + b_var * b_count + delta.square() * count * b_count / total
    return new_mean, m2 / total, total


class ValueNormalizer(nn.Module):
    """Running statistics of the value targets (returns), kept as buffers so checkpoints hold them.

    The value head predicts ``normalize(value)``; ``denormalize`` maps its output back to returns
    for the advantage estimate (rl_games' value normalisation). ``enabled=False`` (rsl_rl's way:
    the value head predicts returns) makes both maps the identity and ``update`` a no-op; the
    buffers stay, so a checkpoint has the same keys either way.
    """

    def __init__(self, eps: float = 1e-5, enabled: bool = True) -> None:
        super().__init__()
        self.eps = float(eps)
        self.enabled = bool(enabled)
        self.register_buffer("mean", torch.zeros((), dtype=torch.float64))
        self.register_buffer("var", torch.ones((), dtype=torch.float64))
        self.register_buffer("count", torch.full((), 1e-4, dtype=torch.float64))

    @torch.no_grad()
    def update(self, returns: torch.Tensor) -> None:
        if not self.enabled:
            return
        self.mean, self.var, self.count = merge_moments(self.mean, self.var, self.count, returns.double())

    def normalize(self, value: torch.Tensor) -> torch.Tensor:
        if not self.enabled:
            return value
        std = (self.var + self.eps).sqrt()
        return ((value - self.mean) / std).to(value.dtype)

    def denormalize(self, value: torch.Tensor) -> torch.Tensor:
        if not self.enabled:
            return value
        std = (self.var + self.eps).sqrt()
        return (value * std + self.mean).to(value.dtype)
