"""The self-supervised part of each PPO minibatch update (the paper's Eq. 2: L = L_PPO + c_aux L_aux).

Per PPO minibatch the loop adds ``c_aux * L_aux`` of one auxiliary minibatch to the PPO loss and
runs ONE backward: the encoder's gradient holds both losses' parts and the PPO optimiser steps
it (lr, gradient-norm clip); this class's optimiser steps only the auxiliary networks (decoders,
forward model, projector) with lr_aux, no clipping. For FD/TFD the target encoder then moves
towards the encoder (TorchRL's ``SoftUpdate``, tau 0.01). Each epoch the auxiliary memory is
split into as many disjoint minibatches as PPO's rollout (single steps for TR/FR, runs of n
steps on a stride-n grid for FD/TFD, see ``AuxMemory.minibatches``).
"""

from __future__ import annotations

from collections.abc import Iterator

import torch
from tensordict import TensorDictBase
from torchrl.objectives import SoftUpdate

from roto_trl.data.memory import AuxMemory
from roto_trl.objectives import ForwardDynamicsLoss
from roto_trl.trainers.errors import NonFiniteError


class AuxiliaryUpdate:
    """An SSL objective with its memory, c_aux, the optimiser of its own networks and (FD/TFD)
    the target-encoder update.

    Args:
        loss: one of ``roto_trl.objectives``' losses, built on the agent's encoder.
        memory: the auxiliary memory it draws minibatches from.
        lr: lr_aux, the auxiliary networks' learning rate.
        coeff: c_aux, the weight of the auxiliary loss in the encoder's objective.
        seq_len: n, for the dynamics objectives.
        tau: target-encoder update rate.
    """

    def __init__(
        self,
        loss,
        memory: AuxMemory,
        *,
        lr: float,
        coeff: float,
        seq_len: int = 1,
        tau: float = 0.01,
    ) -> None:
        self.loss = loss
        self.memory = memory
        self.coeff = float(coeff)
        self.dynamics = isinstance(loss, ForwardDynamicsLoss)
        self.seq_len = int(seq_len) if self.dynamics else 1
        self.optimizer = torch.optim.Adam(loss.auxiliary_parameters(), lr=float(lr), fused=True)
        self.target_update = SoftUpdate(loss, tau=tau) if self.dynamics else None

    def epoch(self, minibatches: int) -> Iterator[TensorDictBase]:
        """This epoch's auxiliary minibatches: the memory in ``minibatches`` disjoint parts
        (fewer, or none, while it holds fewer steps or runs of n steps inside one episode)."""
        return self.memory.minibatches(minibatches, self.seq_len)

    def objective(self, data: TensorDictBase) -> tuple[torch.Tensor, dict[str, float]]:
        """``c_aux * L_aux`` of the minibatch ``data`` (scalar, with gradients) and its numbers:
        ``aux_loss`` (scaled) and the loss's own terms and diagnostics (unscaled)."""
        out = self.loss(data)
        terms = [v for k, v in out.items() if k.startswith("loss_")]
        total = self.coeff * torch.stack(terms).sum()
        if not bool(torch.isfinite(total)):
            bad = [k for k, v in out.items() if k.startswith("loss_") and not torch.isfinite(v)]
            raise NonFiniteError(f"non-finite auxiliary loss {bad}; try a smaller ssl.lr or ssl.coeff")
        return total, {"aux_loss": float(total.detach()), **{k: float(v.detach()) for k, v in out.items()}}

    def zero_grad(self) -> None:
        self.optimizer.zero_grad(set_to_none=True)

    def step(self) -> None:
        """Step the auxiliary networks (after the backward of a loss holding ``objective``), then
        move the target encoder towards the encoder the PPO optimiser has just stepped."""
        self.optimizer.step()
        if self.target_update is not None:
            self.target_update.step()

    def state_dict(self) -> dict:
        """What a checkpoint keeps: the loss (its networks and target encoder) and the optimiser."""
        return {"loss": self.loss.state_dict(), "optimizer": self.optimizer.state_dict()}

    def load_state_dict(self, state: dict) -> None:
        self.loss.load_state_dict(state["loss"])
        try:
            self.optimizer.load_state_dict(state["optimizer"])
        except ValueError as err:
            raise ValueError(
                "the checkpoint's auxiliary optimiser does not fit (written before the auxiliary "
                "optimiser held only the auxiliary networks?); start a new run"
            ) from err
