"""FR: reconstruct the whole observation: TR on the tactile part, MSE on proprioception."""

from __future__ import annotations

from dataclasses import dataclass

from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModule
from tensordict.utils import NestedKey

from roto_trl.objectives.common import EncoderLoss, decoder, required_entry
from roto_trl.objectives.functional import contact_bce, contact_confusion, latent_mse


class FullReconstructionLoss(EncoderLoss):
    """L_FR = BCE(d_tact(z), o_tact) + MSE(d_prop(z), o_prop), one decoder for the whole observation.

    Input: a tensordict ``[B]`` with the encoder's observation entries, ``prop`` ``[B, P]`` and
    (when ``tactile_dim > 0``) ``tactile`` ``[B, K]``. Output: ``loss_prop``, ``loss_tactile``
    and the tactile diagnostics (as ``TactileReconstructionLoss``).

    Args:
        encoder: observation entries -> latent.
        prop_dim, tactile_dim: sizes of the two parts of the observation (tactile may be 0).
        latent_dim: size of the encoder's latent.
        pos_weight: contact weight p_c or ``"auto"``.
    """

    @dataclass
    class _AcceptedKeys:
        """Keys of the input tensordict; change them with ``set_keys(...)``.

        Attributes:
            prop: proprioception to reconstruct (MSE). Defaults to ``"prop"``.
            tactile: binary contacts to reconstruct (BCE). Defaults to ``"tactile"``.
        """

        prop: NestedKey = "prop"
        tactile: NestedKey = "tactile"

    default_keys = _AcceptedKeys

    def __init__(
        self,
        encoder: TensorDictModule,
        prop_dim: int,
        tactile_dim: int,
        *,
        latent_dim: int = 256,
        pos_weight=10.0,
    ) -> None:
        super().__init__(encoder, pos_weight=pos_weight)
        self.prop_dim, self.tactile_dim = int(prop_dim), int(tactile_dim)
        self.observation_decoder = decoder(latent_dim, self.prop_dim + self.tactile_dim)

    def forward(self, tensordict: TensorDictBase) -> TensorDict:
        recon = self.observation_decoder(self.encode(tensordict))
        prop = required_entry(tensordict, self.tensor_keys.prop)
        out = {"loss_prop": latent_mse(recon[..., : self.prop_dim], prop)}
        if self.tactile_dim:
            target = required_entry(tensordict, self.tensor_keys.tactile).float()
            logits = recon[..., self.prop_dim :]
            weight = self.contact_weight(target)
            out["loss_tactile"] = contact_bce(logits, target, weight)
            out.update(contact_confusion(logits, target))
        return TensorDict(out, batch_size=[])
