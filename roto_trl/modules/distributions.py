"""The policy's Gaussian and its deterministic action.

The policy samples actions from a Gaussian; the env clips them to its action bounds (every
task's ``action_spec`` is [-1, 1], ``ACTION_BOUNDS``) before they drive the joints. So the
controller that training shapes is the clipped sample, whose mean is not the Gaussian's mean
when the standard deviation is large next to the distance to a bound: with std 1 (the paper's
initial value, which PPO at a few hundred worlds barely moves in 2 M frames) a mean of 0.8
applies 0.51 on average.

``agent.deterministic_action`` chooses the evaluation action (``ExplorationType.DETERMINISTIC``):

- ``applied_mean`` (default): the mean of the applied action, E[clip(a, low, high)] for
  a ~ N(loc, scale) (:func:`clipped_normal_mean`), the deterministic version of the controller
  that was trained. Measured on Bounce (``bounce_ppo +profile=cpu``, 100 episodes of each
  seed's final policy at 2 M frames): 27.1 / 14.1 / 14.7 bounces per 10 s, against
  3.9 / 4.4 / 3.5 with the Gaussian's mean and 8.1 / 4.2 / 5.6 with samples.
- ``gaussian_mean``: the Gaussian's mean ``loc``, skrl's deterministic action and so the one
  behind the authors' published curves.

The two agree as the standard deviation shrinks (the scale goes to 0: clip(loc)). Training
samples and entropies are the Gaussian's either way.

``agent.action_log_prob`` chooses the log-probability PPO's ratio is made of:

- ``gaussian`` (default; the paper's skrl agent, rsl_rl, CleanRL): the Gaussian's density at the
  unclipped sample. A sample beyond a bound counts by how far beyond it lies, although the env
  applies the bound whatever the distance: with a mean near a bound, PPO's gradient then pushes
  the mean and the standard deviation on differences the env never sees.
- ``clipped``: the probability of the action the env applies (:func:`clipped_normal_log_prob`):
  the density inside the bounds, the Gaussian's mass beyond a bound for a sample at or past it
  (the clipped action policy gradient, Fujita and Maeda 2018). Its policy is the distribution
  of the applied action, whose mean is ``applied_mean``.
  Measured on Bounce (``bounce_ppo +profile=cpu``, 3 seeds, 2 M frames; README "Results on a
  CPU"): best checkpoints 37.2 / 36.1 / 41.5 bounces per 10 s, final policies 14.9 / 20.8 /
  21.6, against 32.1 / 23.8 / 47.4 and 31.1 / 11.0 / 23.2 with ``gaussian`` (an earlier
  session; rerun beside these, seeds 1 and 2 scored 47.2 / 41.9 and 25.3 / 15.2): it falls back
  as the default does. On Find (``find_ppo``, same runs) 0.37 / 0.45 / 0.62 within 3 cm against
  0.53 / 0.50 / 0.67. So the default stays.

The stored action stays the unclipped sample: it lies beyond a bound exactly when the applied
action is the bound, so both choices read the same tensordicts.
"""

from __future__ import annotations

import math

import torch
from torchrl.modules import IndependentNormal

ACTION_BOUNDS = (-1.0, 1.0)  # every task's action_spec; the env clips the policy's samples to it
DETERMINISTIC_ACTIONS = ("applied_mean", "gaussian_mean")
DEFAULT_DETERMINISTIC_ACTION = "applied_mean"  # also for runs saved before the option existed
ACTION_LOG_PROBS = ("gaussian", "clipped")
DEFAULT_ACTION_LOG_PROB = "gaussian"  # also for runs saved before the option existed

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


def clipped_normal_log_prob(
    value: torch.Tensor,
    loc: torch.Tensor,
    scale: torch.Tensor,
    low: float = ACTION_BOUNDS[0],
    high: float = ACTION_BOUNDS[1],
) -> torch.Tensor:
    """log P(clip(a, low, high) = clip(value, low, high)) for a ~ N(loc, scale^2), elementwise.

    Strictly inside the bounds the Gaussian's log-density at ``value``; at or below ``low``
    log Phi((low - loc) / scale), the mass the Gaussian puts below it; at or above ``high``
    log Phi((loc - high) / scale). ``torch.special.log_ndtr`` keeps the tails finite and their
    gradients exact far past a bound. Any matching shapes; ``scale`` > 0.
    """
    inside = torch.distributions.Normal(loc, scale, validate_args=False).log_prob(value)
    below = torch.special.log_ndtr((low - loc) / scale)
    above = torch.special.log_ndtr((loc - high) / scale)
    return torch.where(value <= low, below, torch.where(value >= high, above, inside))


class ClippedActionNormal(IndependentNormal):
    """TorchRL's ``IndependentNormal`` ``[*B, n_actions]`` for actions the env clips to
    ``low``/``high``.

    ``deterministic_action``: the deterministic sample is the mean of the applied action
    (``applied_mean``, :func:`clipped_normal_mean`) or the Gaussian's mean (``gaussian_mean``).
    ``action_log_prob``: ``log_prob`` ``[*B]`` is the Gaussian's (``gaussian``) or the applied
    action's (``clipped``, :func:`clipped_normal_log_prob` summed over the action dimensions).
    Sampling and ``entropy`` are the Gaussian's.
    """

    def __init__(
        self,
        loc: torch.Tensor,
        scale: torch.Tensor,
        low: float = ACTION_BOUNDS[0],
        high: float = ACTION_BOUNDS[1],
        deterministic_action: str = DEFAULT_DETERMINISTIC_ACTION,
        action_log_prob: str = DEFAULT_ACTION_LOG_PROB,
        **kwargs,
    ) -> None:
        self.low, self.high = float(low), float(high)
        self.deterministic_action, self.action_log_prob = deterministic_action, action_log_prob
        super().__init__(loc, scale, **kwargs)

    @property
    def deterministic_sample(self) -> torch.Tensor:
        if self.deterministic_action == "gaussian_mean":
            return self.mean
        return clipped_normal_mean(self.mean, self.stddev, self.low, self.high)

    def log_prob(self, value: torch.Tensor) -> torch.Tensor:
        if self.action_log_prob == "gaussian":
            return super().log_prob(value)
        return clipped_normal_log_prob(value, self.mean, self.stddev, self.low, self.high).sum(-1)


def policy_distribution_kwargs(deterministic_action: str, action_log_prob: str) -> dict[str, str]:
    """``ClippedActionNormal``'s keyword arguments for the agent's two options, or a
    ``ValueError`` naming the choices of the one that is unknown."""
    for key, value, choices in (
        ("deterministic_action", deterministic_action, DETERMINISTIC_ACTIONS),
        ("action_log_prob", action_log_prob, ACTION_LOG_PROBS),
    ):
        if value not in choices:
            raise ValueError(f"agent.{key} must be one of {list(choices)}, got {value!r}")
    return {"deterministic_action": deterministic_action, "action_log_prob": action_log_prob}
