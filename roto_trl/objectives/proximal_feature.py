"""A trust region on the policy encoder's features: Proximal Feature Optimisation (Moalla et al.
2024, "No Representation, No Trust")."""

from __future__ import annotations

from dataclasses import dataclass

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.utils import NestedKey
from torchrl.objectives import LossModule

from roto_trl.modules.agent import LATENT_KEY, ROLLOUT_LATENT_KEY
from roto_trl.objectives.common import required_entry
from roto_trl.objectives.functional import feature_drift
from roto_trl.utils.cli import non_negative_or_off


def checked_feature_coeff(coeff) -> float:
    """``proximal_feature_coeff`` as a float (None: 0, off), or a one-line error."""
    return non_negative_or_off("agent.proximal_feature_coeff", coeff)


class ProximalFeatureLoss(LossModule):
    """L = coeff * mean((z - z_rollout)^2): the policy encoder's latent on a minibatch's states
    kept near the latent the policy computed for them while acting (before this update).

    Why: on Bounce the policy encoder's effective rank falls between the best and the final
    checkpoint in most plain-PPO runs, which fall back, and holds with the FD objective, which
    does not. Moalla et al. tie PPO's collapse to such a falling rank and hold it by penalising
    how far an update moves the features (PFO), as PPO's clip bounds how far it moves the action
    probabilities. They penalise the pre-activations of the actor's layers; this term takes the
    latent the heads read, because the rollout already holds it (written while acting): no extra
    forward pass of the old network. What it did on Bounce (coeff 10, 3 seeds, README "Results on
    a CPU"): the rank stayed at FD's level, and the controller fell back all the same, so it is
    off by default.

    Input: a tensordict ``[B]`` with the new latent ``z`` ``[B, Z]`` (``Agent.encode`` writes it)
    and the acting-time latent ``z_rollout`` ``[B, Z]`` (``ppo.minibatch_loss`` keeps it).
    Output: ``loss_proximal_feature`` and the detached diagnostic ``feature_drift`` (the mean
    squared change, without the weight).

    Args:
        coeff: the term's weight in the PPO minibatch loss (0 or None: the diagnostic only,
            a zero loss without a graph).
    """

    @dataclass
    class _AcceptedKeys:
        """Keys of the input tensordict; change them with ``set_keys(latent=..., rollout_latent=...)``.

        Attributes:
            latent: the policy encoder's latent under the current parameters. Defaults to ``"z"``.
            rollout_latent: the latent written while acting. Defaults to ``"z_rollout"``.
        """

        latent: NestedKey = LATENT_KEY
        rollout_latent: NestedKey = ROLLOUT_LATENT_KEY

    default_keys = _AcceptedKeys

    def __init__(self, *, coeff: float | None = 0.0) -> None:
        super().__init__()
        self.coeff = checked_feature_coeff(coeff)

    def forward(self, tensordict: TensorDictBase) -> TensorDict:
        z = required_entry(tensordict, self.tensor_keys.latent)
        reference = required_entry(tensordict, self.tensor_keys.rollout_latent)
        if z.shape != reference.shape:
            shapes = f"{tuple(z.shape)} against {tuple(reference.shape)}"
            raise ValueError(f"the latent and the rollout latent differ in shape: {shapes}")
        with torch.set_grad_enabled(torch.is_grad_enabled() and self.coeff > 0):
            drift = feature_drift(z, reference)
        loss = self.coeff * drift if self.coeff > 0 else torch.zeros((), dtype=z.dtype, device=z.device)
        return TensorDict({"loss_proximal_feature": loss, "feature_drift": drift.detach()}, batch_size=[])
