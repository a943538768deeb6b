"""A bound on the policy mean's pre-tanh output, against a saturated (state-blind) mean."""

from __future__ import annotations

from dataclasses import dataclass

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.utils import NestedKey
from torchrl.objectives import LossModule

from roto_trl.modules.networks import PolicyHead
from roto_trl.objectives.functional import excess_square
from roto_trl.utils.cli import is_number, non_negative_or_off

SATURATED = 0.9  # |tanh(u)| above this counts as saturated in the diagnostics (|u| > 1.47)
DEFAULT_BOUND = 2.0  # tanh(2) = 0.964, tanh'(2) = 0.07


def checked_mean_bound(bound, coeff) -> tuple[float, float]:
    """``(mean_bound, mean_bound_coeff)`` as floats (None: the defaults, 2.0 and 0), or a one-line error."""
    bound = DEFAULT_BOUND if bound is None else bound
    if not (is_number(bound) and bound > 0):
        raise ValueError(f"agent.mean_bound must be a number > 0, got {bound!r}")
    return float(bound), non_negative_or_off("agent.mean_bound_coeff", coeff)


class PolicyMeanBoundLoss(LossModule):
    """L = coeff * mean(relu(|u| - bound)^2) on the pre-tanh mean u of the policy head.

    Why: the policy's mean is tanh(u), and PPO can drive u past the tanh's knee, where tanh'(u)
    is near 0 and the mean stops answering the state (Bounce with the CPU recipe: 31 % of
    |tanh(u)| > 0.9 on its controller's states at the best checkpoint, 83 % at 4 M frames).
    Inside [-bound, bound] the term is 0, so it only pulls back what has run past the knee.
    Measured in the README ("Results on a CPU"): on Bounce bound 1.0 removes the saturation,
    holds 2 of 3 seeds and raises the mean final policy (with the recipe's critic from 21.8 to
    29.9 bounces per 10 s), but one seed falls back without any saturation. Off by default:
    a bound of 1.0 also keeps the mean action within tanh(1) = 0.76 of each joint's range, and
    on Find it scored less (see the README). With ``coeff`` 0 it
    returns a zero loss without a graph and only the diagnostics.

    Input: a tensordict ``[B]`` with the latent ``z`` ``[B, Z]`` (``Agent.encode`` writes it).
    Output: ``loss_mean_bound`` and the detached diagnostics ``mean_saturation`` (the fraction of
    |tanh(u)| > 0.9) and ``mean_preactivation_abs`` (mean |u|).

    Args:
        policy_head: the agent's ``PolicyHead`` (its parameters, not a copy).
        bound: |u| allowed without penalty (2.0: tanh 0.964, tanh' 0.07; None: 2.0).
        coeff: the term's weight in the PPO minibatch loss (0 or None: diagnostics only).
    """

    @dataclass
    class _AcceptedKeys:
        """Keys of the input tensordict; change them with ``set_keys(latent=...)``.

        Attributes:
            latent: the policy encoder's latent. Defaults to ``"z"``.
        """

        latent: NestedKey = "z"

    default_keys = _AcceptedKeys

    def __init__(
        self, policy_head: PolicyHead, *, bound: float | None = DEFAULT_BOUND, coeff: float | None = 0.0
    ) -> None:
        super().__init__()
        self.policy_head = policy_head
        self.bound, self.coeff = checked_mean_bound(bound, coeff)

    def forward(self, tensordict: TensorDictBase) -> TensorDict:
        z = tensordict.get(self.tensor_keys.latent)
        with torch.set_grad_enabled(torch.is_grad_enabled() and self.coeff > 0):
            u = self.policy_head.preactivation(z)
            loss = self.coeff * excess_square(u, self.bound)
        detached = u.detach()
        out = {
            "loss_mean_bound": loss,
            "mean_saturation": (detached.tanh().abs() > SATURATED).float().mean(),
            "mean_preactivation_abs": detached.abs().mean(),
        }
        return TensorDict(out, batch_size=[])
