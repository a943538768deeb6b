"""The policy's Gaussian and its deterministic action.

The policy samples actions from a Gaussian; the env clips them to its action bounds (every
task's ``action_spec`` is [-1, 1], ``ACTION_BOUNDS``) before they drive the joints. So the
controller that training shapes is the clipped sample, whose mean is not the Gaussian's mean
when the standard deviation is large next to the distance to a bound: with std 1 (the paper's
initial value) a mean of 0.8 applies 0.51 on average.

``agent.deterministic_action`` chooses the evaluation action (``ExplorationType.DETERMINISTIC``):

- ``applied_mean`` (default): the mean of the applied action, E[clip(a, low, high)] for
  a ~ N(loc, scale) (:func:`clipped_normal_mean`), the deterministic version of the controller
  that was trained;
- ``gaussian_mean``: the Gaussian's mean ``loc``, skrl's deterministic action and so the one
  behind the authors' published curves.

The two agree as the standard deviation shrinks. Training samples, log-probabilities and
entropies are the Gaussian's either way. How the two compare: docs/results_cpu.md.
"""

from __future__ import annotations

import math

import torch
from torchrl.modules import IndependentNormal

ACTION_BOUNDS = (-1.0, 1.0)  # every task's action_spec; the env clips the policy's samples to it
DETERMINISTIC_ACTIONS = ("applied_mean", "gaussian_mean")

_INV_SQRT_2PI = 1.0 / math.sqrt(2.0 * math.pi)


def clipped_normal_mean(
    loc: torch.Tensor, scale: torch.Tensor, low: float = ACTION_BOUNDS[0], high: float = ACTION_BOUNDS[1]
) -> torch.Tensor:
    """E[clip(a, low, high)] for a ~ N(loc, scale^2), elementwise (any matching shapes).

    With a = (low - loc) / scale, b = (high - loc) / scale, Phi and phi the standard normal's CDF
    and density: low Phi(a) + high (1 - Phi(b)) + loc (Phi(b) - Phi(a)) + scale (phi(a) - phi(b)).
    ``scale`` must be > 0 (the policy's is exp of a log-std clamped at -20).
    """
    a = (low - loc) / scale
    b = (high - loc) / scale
    cdf_a, cdf_b = torch.special.ndtr(a), torch.special.ndtr(b)
    pdf_a = torch.exp(-0.5 * a.square()) * _INV_SQRT_2PI
    pdf_b = torch.exp(-0.5 * b.square()) * _INV_SQRT_2PI
    return low * cdf_a + high * (1.0 - cdf_b) + loc * (cdf_b - cdf_a) + scale * (pdf_a - pdf_b)


class ClippedActionNormal(IndependentNormal):
    """TorchRL's ``IndependentNormal`` ``[*B, n_actions]`` for actions the env clips to
    ``low``/``high``, whose deterministic sample is the mean of the applied action
    (``applied_mean``, :func:`clipped_normal_mean`) or the Gaussian's mean (``gaussian_mean``).
    Sampling, ``log_prob`` and ``entropy`` are the Gaussian's."""

    def __init__(
        self,
        loc: torch.Tensor,
        scale: torch.Tensor,
        low: float = ACTION_BOUNDS[0],
        high: float = ACTION_BOUNDS[1],
        deterministic_action: str = "applied_mean",
        **kwargs,
    ) -> None:
        if deterministic_action not in DETERMINISTIC_ACTIONS:
            choices = list(DETERMINISTIC_ACTIONS)
            raise ValueError(f"deterministic_action must be one of {choices}, got {deterministic_action!r}")
        self.low, self.high = float(low), float(high)
        self.deterministic_action = deterministic_action
        super().__init__(loc, scale, **kwargs)

    @property
    def deterministic_sample(self) -> torch.Tensor:
        if self.deterministic_action == "gaussian_mean":
            return self.mean
        return clipped_normal_mean(self.mean, self.stddev, self.low, self.high)
