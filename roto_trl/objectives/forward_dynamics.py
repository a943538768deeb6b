"""FD and TFD: predict future latents from the current one and the actions taken.

FD: ẑ_{t+1} = f(z_t, a_t), ẑ_{t+i+1} = f(ẑ_{t+i}, a_{t+i}) (autoregressive), and
    L_FD = Σ_{i=1}^{n-1} MSE(p(ẑ_{t+i}), e_T(o_{t+i})), with p a projector and e_T an EMA copy of
    the encoder (update it after each step with ``SoftUpdate(loss, tau=0.01)``).
TFD: L_FD + Σ_{i=1}^{n-1} BCE(d(ẑ_{t+i}), o_tact_{t+i}), the tactile decoder applied to each
    predicted latent.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModule
from tensordict.utils import NestedKey
from torch import nn

from roto_trl.modules.networks import mlp
from roto_trl.objectives.common import EncoderLoss, decoder, required_entry
from roto_trl.objectives.functional import contact_bce, contact_confusion, latent_mse, rollout_latents

FORWARD_SIZES = (512, 256)
PROJECTOR_SIZE = 256


class ForwardDynamicsLoss(EncoderLoss):
    """L_FD over sequences of length n.

    Input: a tensordict ``[B, n]`` of consecutive steps of one episode each (the encoder's
    observation entries and ``action`` ``[B, n, A]``). Output: ``loss_dynamics`` (the sum over
    the n - 1 horizons of the mean MSE) and ``mse_h<i>`` per horizon (detached).

    Args:
        encoder: observation entries -> latent.
        action_dim: A.
        latent_dim: size of the latent.
    """

    @dataclass
    class _AcceptedKeys:
        """Keys of the input tensordict; change them with ``set_keys(action=...)``.

        Attributes:
            action: the action taken at each step. Defaults to ``"action"``.
        """

        action: NestedKey = "action"

    default_keys = _AcceptedKeys

    def __init__(
        self, encoder: TensorDictModule, action_dim: int, *, latent_dim: int = 256, pos_weight=None
    ) -> None:
        super().__init__(encoder, pos_weight=pos_weight, target_encoder=True)
        self.forward_model = nn.Sequential(
            mlp(latent_dim + int(action_dim), FORWARD_SIZES, layer_norm=False),
            nn.Linear(FORWARD_SIZES[-1], latent_dim),
        )
        self.projector = nn.Sequential(
            mlp(latent_dim, (PROJECTOR_SIZE,), layer_norm=False), nn.Linear(PROJECTOR_SIZE, latent_dim)
        )

    def _predict(self, tensordict: TensorDictBase) -> tuple[torch.Tensor, torch.Tensor]:
        """Predicted ``[B, n-1, Z]`` and target ``[B, n-1, Z]`` latents of steps t+1 .. t+n-1."""
        if tensordict.batch_dims != 2 or tensordict.shape[1] < 2:
            raise ValueError(
                f"forward dynamics needs sequences [B, n >= 2], got batch {list(tensordict.shape)}"
            )
        z0 = self.encode(tensordict[:, 0])
        actions = required_entry(tensordict, self.tensor_keys.action)[:, :-1]
        predicted = rollout_latents(self.forward_model, z0, actions)
        target = self.encode_target(tensordict[:, 1:])
        return predicted, target

    def _dynamics(self, tensordict: TensorDictBase) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """The predicted latents ``[B, n-1, Z]`` and L_FD's outputs: ``loss_dynamics`` and the
        detached ``mse_h<i>`` of each horizon."""
        predicted, target = self._predict(tensordict)
        projected = self.projector(predicted)
        per_horizon = [latent_mse(projected[:, i], target[:, i]) for i in range(predicted.shape[1])]
        out = {"loss_dynamics": torch.stack(per_horizon).sum()}
        out.update({f"mse_h{i + 1}": v.detach() for i, v in enumerate(per_horizon)})
        return predicted, out

    def forward(self, tensordict: TensorDictBase) -> TensorDict:
        return TensorDict(self._dynamics(tensordict)[1], batch_size=[])


class TactileForwardDynamicsLoss(ForwardDynamicsLoss):
    """L_TFD = L_FD + Σ_i BCE(d(ẑ_{t+i}), o_tact_{t+i}).

    Input as ``ForwardDynamicsLoss`` plus ``tactile`` ``[B, n, K]``. Output: ``loss_dynamics``,
    ``loss_tactile`` (summed over horizons) and per horizon ``mse_h<i>``, ``tpr_h<i>``,
    ``fpr_h<i>``, ``fnr_h<i>``, ``tnr_h<i>``, ``accuracy_h<i>``, ``precision_h<i>``.

    Args: as ``ForwardDynamicsLoss``, plus ``tactile_dim`` (K) and ``pos_weight``.
    """

    @dataclass
    class _AcceptedKeys:
        """Keys of the input tensordict; change them with ``set_keys(...)``.

        Attributes:
            action: the action taken at each step. Defaults to ``"action"``.
            tactile: the binary tactile observation at each step. Defaults to ``"tactile"``.
        """

        action: NestedKey = "action"
        tactile: NestedKey = "tactile"

    default_keys = _AcceptedKeys

    def __init__(
        self,
        encoder: TensorDictModule,
        action_dim: int,
        tactile_dim: int,
        *,
        latent_dim: int = 256,
        pos_weight=10.0,
    ) -> None:
        super().__init__(encoder, action_dim, latent_dim=latent_dim, pos_weight=pos_weight)
        self.tactile_decoder = decoder(latent_dim, tactile_dim)

    @torch.no_grad()
    def predict_tactile(self, tensordict: TensorDictBase) -> torch.Tensor:
        """Contact probabilities ``[B, n-1, K]`` of steps t+1 .. t+n-1, predicted from the latent
        of step t and the actions of a sequence ``tensordict`` ``[B, n]`` (the loss's horizons)."""
        predicted, _ = self._predict(tensordict)
        return torch.sigmoid(self.tactile_decoder(predicted))

    def forward(self, tensordict: TensorDictBase) -> TensorDict:
        predicted, out = self._dynamics(tensordict)
        tactile = required_entry(tensordict, self.tensor_keys.tactile)[:, 1:].float()
        logits = self.tactile_decoder(predicted)
        weight = self.contact_weight(tactile)
        bce = []
        for i in range(predicted.shape[1]):
            bce.append(contact_bce(logits[:, i], tactile[:, i], weight))
            out.update(
                {f"{k}_h{i + 1}": v for k, v in contact_confusion(logits[:, i], tactile[:, i]).items()}
            )
        out["loss_tactile"] = torch.stack(bce).sum()
        out["pos_weight"] = float(weight)
        return TensorDict(out, batch_size=[])
