"""The agent's networks (SPEC "The agent"): a shared encoder, a Gaussian policy head, a value head.

Plain ``nn.Module``s over tensors; ``roto_trl.modules.agent`` wraps them as TorchRL modules.
"""

from __future__ import annotations

import torch
from torch import nn

ENCODER_SIZES = (1024, 512, 256)
HEAD_SIZES = (128, 64)
LOG_STD_RANGE = (-20.0, 2.0)  # the authors' clamp of the policy's log standard deviation


def mlp(in_dim: int, sizes: tuple[int, ...], *, layer_norm: bool) -> nn.Sequential:
    """Linear layers of ``sizes``, each followed by (LayerNorm and) ELU."""
    layers: list[nn.Module] = []
    for size in sizes:
        layers.append(nn.Linear(in_dim, size))
        if layer_norm:
            layers.append(nn.LayerNorm(size))
        layers.append(nn.ELU())
        in_dim = size
    return nn.Sequential(*layers)


class Encoder(nn.Module):
    """Observation -> latent ``z``: o -> 1024 -> 512 -> 256, LayerNorm + ELU after each layer.

    ``forward(*parts)`` takes the observation parts (``prop`` ``[*B, k*P]``, optionally
    ``tactile`` ``[*B, k*T]``), concatenates them and returns ``z`` ``[*B, 256]``.
    """

    def __init__(self, obs_dim: int, sizes: tuple[int, ...] = ENCODER_SIZES) -> None:
        super().__init__()
        self.obs_dim = int(obs_dim)
        self.net = mlp(self.obs_dim, tuple(sizes), layer_norm=True)
        self.latent_dim = int(sizes[-1])

    def forward(self, *parts: torch.Tensor) -> torch.Tensor:
        obs = parts[0] if len(parts) == 1 else torch.cat(parts, dim=-1)
        if obs.shape[-1] != self.obs_dim:
            raise ValueError(f"encoder expects {self.obs_dim} observation features, got {obs.shape[-1]}")
        return self.net(obs)


class PolicyHead(nn.Module):
    """``z`` -> (loc, scale) of a diagonal Gaussian: z -> 128 -> 64 -> n_actions, ELU, tanh mean.

    The log standard deviation is a learned vector independent of the state, clamped to
    ``LOG_STD_RANGE`` (no gradient pushes it further once it sits at a bound).

    Returns:
        ``loc`` ``[*B, n_actions]`` in (-1, 1) and ``scale`` ``[*B, n_actions]`` > 0.
    """

    def __init__(self, latent_dim: int, n_actions: int, init_log_std: float = 0.0) -> None:
        super().__init__()
        self.body = mlp(latent_dim, HEAD_SIZES, layer_norm=False)
        self.mean = nn.Linear(HEAD_SIZES[-1], n_actions)
        self.log_std = nn.Parameter(torch.full((n_actions,), float(init_log_std)))

    def preactivation(self, z: torch.Tensor) -> torch.Tensor:
        """The mean before its tanh ``[*B, n_actions]`` (``PolicyMeanBoundLoss`` bounds it)."""
        return self.mean(self.body(z))

    def forward(self, z: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        loc = torch.tanh(self.preactivation(z))
        return loc, self.log_std.clamp(*LOG_STD_RANGE).exp().expand_as(loc)


class ValueHead(nn.Module):
    """``z`` -> normalised state value ``[*B, 1]``: z -> 128 -> 64 -> 1, ELU."""

    def __init__(self, latent_dim: int) -> None:
        super().__init__()
        self.net = nn.Sequential(mlp(latent_dim, HEAD_SIZES, layer_norm=False), nn.Linear(HEAD_SIZES[-1], 1))

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        return self.net(z)
