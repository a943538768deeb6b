"""The agent's networks (the paper's Appendix A): a shared encoder, a Gaussian policy head, a value head.

Plain ``nn.Module``s over tensors; ``roto_trl.modules.agent`` wraps them as TorchRL modules.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import torch
from torch import nn

ENCODER_SIZES = (1024, 512, 256)
HEAD_SIZES = (128, 64)
LOG_STD_RANGE = (-20.0, 2.0)  # the authors' clamp of the policy's log standard deviation
PRECISIONS = ("float32", "bfloat16")  # the hidden layers' arithmetic (``hidden_precision``)
AUTO_PRECISION = "auto"  # a config value only: ``resolved_precision`` picks one of PRECISIONS


def checked_precision(precision: str, allowed: tuple[str, ...] = PRECISIONS) -> str:
    """``precision`` if it is one of ``allowed``, else a one-line error."""
    if precision not in allowed:
        raise ValueError(f"agent.precision must be one of {', '.join(allowed)}, got {precision!r}")
    return precision


def resolved_precision(precision: str, device: str) -> str:
    """``agent.precision`` as the networks run it: ``auto`` is ``bfloat16`` on a CPU that multiplies
    bfloat16 in hardware (``cpu_has_bfloat16``) and ``float32`` elsewhere (another CPU, CUDA);
    ``float32`` and ``bfloat16`` stay as they are. ``train.py`` saves the resolved value in the
    run's config, so that a run evaluated or resumed on another machine keeps its arithmetic."""
    precision = checked_precision(precision, (*PRECISIONS, AUTO_PRECISION))
    if precision != AUTO_PRECISION:
        return precision
    return "bfloat16" if on_cpu(device) and cpu_has_bfloat16() else "float32"


def on_cpu(device) -> bool:
    """Whether ``device`` (``cpu``, ``cuda:1``, or a name torch cannot parse) names the CPU,
    without parsing it: ``check_device`` gives the one-line error for a bad name."""
    return str(device).split(":")[0] == "cpu"


def cpu_has_bfloat16() -> bool:
    """Whether this CPU multiplies bfloat16 matrices in hardware (AVX512-BF16 or AMX); without,
    torch emulates them and ``agent.precision=bfloat16`` runs slower than float32."""
    return torch.cpu._is_avx512_bf16_supported() or torch.cpu._is_amx_tile_supported()


@contextlib.contextmanager
def bfloat16_products() -> Iterator[None]:
    """float32 matrix products computed by oneDNN in bfloat16 (both factors rounded to bfloat16's
    8 bits, sums and results in float32) inside the block; everything else stays float32."""
    before = torch.backends.mkldnn.matmul.fp32_precision
    torch.backends.mkldnn.matmul.fp32_precision = "bf16"
    try:
        yield
    finally:
        torch.backends.mkldnn.matmul.fp32_precision = before


def hidden_precision(precision: str) -> contextlib.AbstractContextManager:
    """The context the hidden layers (and the update's backward, ``minibatch_step``) run in:
    ``bfloat16_products`` for bfloat16, nothing for float32.

    Only the products' factors are rounded; activations, LayerNorm, weights and the optimiser
    stay float32: autocast, which also rounds the activations and LayerNorm, learned less
    (docs/recipe.md, precision).
    """
    return bfloat16_products() if precision == "bfloat16" else contextlib.nullcontext()


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
    ``tactile`` ``[*B, k*T]``), concatenates them and returns ``z`` ``[*B, 256]`` in float32
    (its products computed in ``precision``, see ``hidden_precision``).
    """

    def __init__(
        self, obs_dim: int, sizes: tuple[int, ...] = ENCODER_SIZES, precision: str = "float32"
    ) -> None:
        super().__init__()
        self.obs_dim = int(obs_dim)
        self.net = mlp(self.obs_dim, tuple(sizes), layer_norm=True)
        self.latent_dim = int(sizes[-1])
        self.precision = checked_precision(precision)

    def forward(self, *parts: torch.Tensor) -> torch.Tensor:
        obs = parts[0] if len(parts) == 1 else torch.cat(parts, dim=-1)
        if obs.shape[-1] != self.obs_dim:
            raise ValueError(f"encoder expects {self.obs_dim} observation features, got {obs.shape[-1]}")
        with hidden_precision(self.precision):
            return self.net(obs)


class PolicyHead(nn.Module):
    """``z`` -> (loc, scale) of a diagonal Gaussian: z -> 128 -> 64 -> n_actions, ELU, tanh mean.

    The log standard deviation is a learned vector independent of the state, clamped to
    ``LOG_STD_RANGE`` (no gradient pushes it further once it sits at a bound). The hidden layers'
    products run in ``precision``; the output layer's always in float32, so that the mean PPO's
    ratio reads does not come from factors rounded to bfloat16's 8 bits.

    Returns:
        ``loc`` ``[*B, n_actions]`` in (-1, 1) and ``scale`` ``[*B, n_actions]`` > 0.
    """

    def __init__(
        self, latent_dim: int, n_actions: int, init_log_std: float = 0.0, precision: str = "float32"
    ) -> None:
        super().__init__()
        self.body = mlp(latent_dim, HEAD_SIZES, layer_norm=False)
        self.mean = nn.Linear(HEAD_SIZES[-1], n_actions)
        self.log_std = nn.Parameter(torch.full((n_actions,), float(init_log_std)))
        self.precision = checked_precision(precision)

    def preactivation(self, z: torch.Tensor) -> torch.Tensor:
        """The mean before its tanh ``[*B, n_actions]`` (``PolicyMeanBoundLoss`` bounds it)."""
        with hidden_precision(self.precision):
            hidden = self.body(z)
        return self.mean(hidden)

    def forward(self, z: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        loc = torch.tanh(self.preactivation(z))
        return loc, self.log_std.clamp(*LOG_STD_RANGE).exp().expand_as(loc)


class ValueHead(nn.Module):
    """``z`` -> normalised state value ``[*B, 1]``: z -> 128 -> 64 -> 1, ELU (the hidden layers'
    products in ``precision``, the output layer's in float32)."""

    def __init__(self, latent_dim: int, precision: str = "float32") -> None:
        super().__init__()
        self.net = nn.Sequential(mlp(latent_dim, HEAD_SIZES, layer_norm=False), nn.Linear(HEAD_SIZES[-1], 1))
        self.precision = checked_precision(precision)

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        body, out = self.net
        with hidden_precision(self.precision):
            hidden = body(z)
        return out(hidden)
