"""TR: reconstruct the tactile observation from the latent (BCE on logits, weighted contacts)."""

from __future__ import annotations

from dataclasses import dataclass

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModule
from tensordict.utils import NestedKey

from roto_trl.objectives.common import EncoderLoss, decoder, required_entry
from roto_trl.objectives.functional import contact_bce, contact_confusion


class TactileReconstructionLoss(EncoderLoss):
    """L_TR = BCE(d(e(o)), o_tact) with contacts weighted by ``pos_weight``.

    Input: a tensordict ``[B]`` with the encoder's observation entries and ``tactile`` ``[B, K]``
    (0/1, any dtype). Output: ``loss_tactile`` and detached diagnostics ``tpr``, ``fpr``,
    ``fnr``, ``tnr``, ``accuracy``, ``precision``, ``pos_weight``.

    Args:
        encoder: observation entries -> latent (trained by this loss too).
        tactile_dim: K, the size of the tactile observation to reconstruct.
        latent_dim: size of the encoder's latent.
        pos_weight: contact weight p_c (paper: 10) or ``"auto"``.
    """

    @dataclass
    class _AcceptedKeys:
        """Keys of the input tensordict; change them with ``set_keys(tactile=...)``.

        Attributes:
            tactile: the binary tactile observation to reconstruct. Defaults to ``"tactile"``.
        """

        tactile: NestedKey = "tactile"

    default_keys = _AcceptedKeys

    def __init__(
        self, encoder: TensorDictModule, tactile_dim: int, *, latent_dim: int = 256, pos_weight=10.0
    ) -> None:
        super().__init__(encoder, pos_weight=pos_weight)
        self.tactile_decoder = decoder(latent_dim, tactile_dim)

    @torch.no_grad()
    def predict_tactile(self, tensordict: TensorDictBase) -> torch.Tensor:
        """Contact probabilities ``[*B, K]`` reconstructed from the latent of ``tensordict`` ``[*B]``."""
        return torch.sigmoid(self.tactile_decoder(self.encode(tensordict)))

    def forward(self, tensordict: TensorDictBase) -> TensorDict:
        target = required_entry(tensordict, self.tensor_keys.tactile).float()
        logits = self.tactile_decoder(self.encode(tensordict))
        weight = self.contact_weight(target)
        out = {"loss_tactile": contact_bce(logits, target, weight), "pos_weight": float(weight)}
        out.update(contact_confusion(logits, target))
        return TensorDict(out, batch_size=[])
