"""The auxiliary (self-supervised) step that follows each PPO minibatch step.

One step: draw a minibatch from the auxiliary memory (single steps for TR/FR, runs of n steps for
FD/TFD), compute the objective, scale it by c_aux, and step its own optimiser (encoder +
auxiliary networks, lr_aux, no gradient clipping); for FD/TFD then move the target encoder
towards the encoder (TorchRL's ``SoftUpdate``, tau 0.01).
"""

from __future__ import annotations

import torch
from torchrl.objectives import SoftUpdate

from roto_trl.data.memory import AuxMemory
from roto_trl.objectives import ForwardDynamicsLoss
from roto_trl.trainers.errors import NonFiniteError


class AuxiliaryUpdate:
    """An SSL objective with its optimiser, memory and (FD/TFD) target-encoder update.

    Args:
        loss: one of ``roto_trl.objectives``' losses.
        memory: the auxiliary memory it samples from.
        lr: lr_aux.
        coeff: c_aux.
        batch: observations per auxiliary minibatch (runs of n steps count n each).
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
        batch: int,
        seq_len: int = 1,
        tau: float = 0.01,
    ) -> None:
        self.loss = loss
        self.memory = memory
        self.coeff = float(coeff)
        self.seq_len = int(seq_len)
        self.dynamics = isinstance(loss, ForwardDynamicsLoss)
        self.batch = max(1, int(batch) // self.seq_len) if self.dynamics else int(batch)
        self.optimizer = torch.optim.Adam(loss.parameters(), lr=float(lr))
        self.target_update = SoftUpdate(loss, tau=tau) if self.dynamics else None

    def step(self) -> dict[str, float] | None:
        """One auxiliary step; returns its (scaled) loss and diagnostics as floats.

        Returns None, and steps nothing, when the memory holds no run of n steps inside one
        episode yet (episodes shorter than n, e.g. early on with few worlds).
        """
        if self.dynamics:
            if not bool(self.memory.valid_starts(self.seq_len).any()):
                return None
            data = self.memory.sample_sequences(self.batch, self.seq_len)
        else:
            data = self.memory.sample(self.batch)
        out = self.loss(data)
        terms = [v for k, v in out.items() if k.startswith("loss_")]
        total = self.coeff * torch.stack(terms).sum()
        if not bool(torch.isfinite(total)):
            bad = [k for k, v in out.items() if k.startswith("loss_") and not torch.isfinite(v)]
            raise NonFiniteError(f"non-finite auxiliary loss {bad}; try a smaller ssl.lr")
        self.optimizer.zero_grad(set_to_none=True)
        total.backward()
        self.optimizer.step()
        if self.target_update is not None:
            self.target_update.step()
        return {"aux_loss": float(total.detach()), **{k: float(v.detach()) for k, v in out.items()}}
