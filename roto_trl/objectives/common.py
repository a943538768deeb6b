"""What the self-supervised losses share: the encoder they train and the contact weighting."""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModule, TensorDictParams
from torch import nn
from torchrl.objectives import LossModule

from roto_trl.modules.networks import mlp
from roto_trl.objectives.functional import auto_pos_weight

DECODER_SIZES = (512, 512)


def required_entry(td: TensorDictBase, key) -> torch.Tensor:
    """``td[key]``, or a ``KeyError`` naming the key and how to point a loss elsewhere."""
    value = td.get(key, None)
    if value is None:
        raise KeyError(f"the input has no {key!r} entry; name the right one with loss.set_keys(...)")
    return value


def decoder(latent_dim: int, out_dim: int, sizes: tuple[int, ...] = DECODER_SIZES) -> nn.Sequential:
    """z -> 512 -> 512 -> ``out_dim`` (ELU after the hidden layers, linear output)."""
    return nn.Sequential(mlp(latent_dim, sizes, layer_norm=False), nn.Linear(sizes[-1], out_dim))


class EncoderLoss(LossModule):
    """Base of the self-supervised losses: holds the encoder (a ``TensorDictModule`` from the
    observation entries to one latent entry) as TorchRL's functional ``encoder_network``.

    The encoder's parameters are the ones given (shared with the agent, not copied), so an
    optimiser over ``loss.parameters()`` trains the encoder and this loss's own networks;
    ``auxiliary_parameters()`` are this loss's own networks alone (for an optimiser beside one
    that already steps the encoder).

    Args:
        encoder: observation entries -> latent ``[*B, Z]``.
        pos_weight: weight of contacts in the tactile BCE, or ``"auto"`` (inverse contact rate of
            each minibatch, clamped to [1, 100]); None for a loss without a tactile term.
        target_encoder: keep an EMA copy of the encoder (``target_encoder_network_params``),
            updated with TorchRL's ``SoftUpdate(loss, tau=...)``.
    """

    # declared for TorchRL's convert_to_functional, which warns about undeclared module names
    encoder_network: TensorDictModule
    encoder_network_params: TensorDictParams
    target_encoder_network_params: TensorDictParams

    def __init__(
        self,
        encoder: TensorDictModule,
        *,
        pos_weight: float | str | None = 10.0,
        target_encoder: bool = False,
    ) -> None:
        super().__init__()
        if pos_weight is not None and not (
            pos_weight == "auto" or (isinstance(pos_weight, int | float) and pos_weight > 0)
        ):
            raise ValueError(f"pos_weight must be a positive number or 'auto', got {pos_weight!r}")
        self.pos_weight = pos_weight
        self.latent_key = encoder.out_keys[0]
        self.convert_to_functional(encoder, "encoder_network", create_target_params=target_encoder)

    def encode(self, td: TensorDictBase) -> torch.Tensor:
        """Latent of ``td``'s observations with the online encoder (gradients flow)."""
        with self.encoder_network_params.to_module(self.encoder_network):
            return self.encoder_network(td.select(*self.encoder_network.in_keys))[self.latent_key]

    def auxiliary_parameters(self) -> list[nn.Parameter]:
        """This loss's own networks' parameters: ``parameters()`` without the encoder's."""
        encoder = {id(p) for p in self.encoder_network_params.values(True, True)}
        return [p for p in self.parameters() if id(p) not in encoder]

    @torch.no_grad()
    def encode_target(self, td: TensorDictBase) -> torch.Tensor:
        """Latent of ``td``'s observations with the EMA target encoder (no gradients).

        The target tensors go into the encoder through a plain view (``.data``): swapped in
        from the ``TensorDictParams`` itself they would come back wrapped as parameters that
        require gradients, and a ``SoftUpdate`` built afterwards refuses them.
        """
        with self.target_encoder_network_params.data.to_module(self.encoder_network):
            return self.encoder_network(td.select(*self.encoder_network.in_keys))[self.latent_key]

    def contact_weight(self, target: torch.Tensor) -> torch.Tensor | float:
        return auto_pos_weight(target) if self.pos_weight == "auto" else float(self.pos_weight)
