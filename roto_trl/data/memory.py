"""The separated auxiliary memory: the last N_rollouts rollouts, from which SSL minibatches come.

Rollouts ``[B, R]`` (B worlds, R steps) are kept FIFO in a ``TensorDictReplayBuffer`` whose
storage holds ``[N_rollouts, B, R, ...]``; N_rollouts = 1 is exactly the current rollout. Only
what the objectives need is stored: the observation entries (tactile as uint8, 4x smaller than
float32), the action the env applied (the policy's sample clipped to the action bounds) and the
``done`` flag of each step.

Minibatches: ``minibatches(count, n)`` is one pass over the memory in ``count`` disjoint
minibatches of random order, as PPO passes over its rollout: every stored step (n = 1, ``[b]``)
or every run of n consecutive steps that never crosses an episode end (``[b, n]``): no step but
the last of a run may be ``done`` (terminated or truncated), since the next observation after a
done step belongs to a new episode. TorchRL's ``SliceSampler`` works on flat trajectory
storages; this layout is indexed directly instead.
"""

from __future__ import annotations

from collections.abc import Iterator

import torch
from tensordict import TensorDictBase
from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer

BOOL_KEYS = ("tactile",)  # 0/1 observations stored as uint8


class AuxMemory:
    """FIFO memory of whole rollouts for the auxiliary losses.

    Args:
        num_rollouts: N_rollouts, rollouts kept (oldest dropped first).
        obs_keys: observation entries to keep (``prop``, ``tactile``).
        device: where the memory lives.
        action_bounds: ``(low, high)`` of the env's action (floats or ``[A]`` tensors); the stored
            action is the rollout's ``action`` clipped to them, what the env applied. None keeps
            the action as given (a policy whose samples are already within bounds).
    """

    def __init__(
        self, num_rollouts: int, obs_keys: tuple[str, ...], device="cpu", action_bounds=None
    ) -> None:
        if int(num_rollouts) < 1:
            raise ValueError(f"the auxiliary memory must hold >= 1 rollout, got {num_rollouts}")
        self.num_rollouts = int(num_rollouts)
        self.obs_keys = tuple(obs_keys)
        self.action_bounds = action_bounds
        self.buffer = TensorDictReplayBuffer(storage=LazyTensorStorage(self.num_rollouts, device=device))
        self._valid: dict[int, torch.Tensor] = {}

    def __len__(self) -> int:
        return len(self.buffer)

    def add(self, rollout: TensorDictBase) -> None:
        """Store a rollout ``[B, R]`` (the collector's batch), dropping the oldest when full."""
        keep = rollout.select(*self.obs_keys, "action")
        if self.action_bounds is not None:
            low, high = (torch.as_tensor(b, device=keep.device) for b in self.action_bounds)
            keep.set("action", torch.clamp(keep.get("action"), low, high))
        for key in BOOL_KEYS:
            if key in keep:
                keep.set(key, keep.get(key).to(torch.uint8))
        keep.set("done", rollout.get(("next", "done")).reshape(rollout.shape))
        self.buffer.extend(keep.unsqueeze(0))
        self._valid.clear()

    def stored(self) -> TensorDictBase:
        """Everything stored, ``[M, B, R]`` (M <= N_rollouts), oldest first is not guaranteed."""
        return self.buffer.storage[: len(self.buffer)]

    def nbytes(self) -> int:
        """Bytes the stored rollouts take."""
        return sum(t.numel() * t.element_size() for t in self.stored().values(True, True))

    @staticmethod
    def _as_float(td: TensorDictBase) -> TensorDictBase:
        for key in BOOL_KEYS:
            if key in td:
                td.set(key, td.get(key).float())
        return td

    def valid_starts(self, n: int) -> torch.Tensor:
        """``[M, B, R]`` bool: a run of n steps may start here (it fits and crosses no episode end)."""
        if n not in self._valid:
            done = self.stored().get("done").squeeze(-1)  # [M, B, R]
            m, b, r = done.shape
            valid = torch.zeros(m, b, r, dtype=torch.bool, device=done.device)
            if n <= r:
                # done among steps t .. t+n-2: a window sum over the first n-1 steps of each run
                csum = torch.nn.functional.pad(done.long().cumsum(-1), (1, 0))
                crossings = csum[..., n - 1 :] - csum[..., : r - n + 2]  # [M, B, r - n + 2]
                valid[..., : r - n + 1] = crossings[..., : r - n + 1] == 0
            self._valid[n] = valid
        return self._valid[n]

    def minibatches(
        self, count: int, n: int = 1, generator: torch.Generator | None = None
    ) -> Iterator[TensorDictBase]:
        """One pass over the memory: ``count`` disjoint minibatches (fewer when fewer than
        ``count`` steps or runs are stored), in random order: every stored step once (n = 1:
        minibatches ``[b]``), or runs of n steps inside one episode (``[b, n]``) that start on a
        grid of stride n with a random offset, so that no step is in two runs of a pass.

        Why the grid: with every start, each step would be encoded n times per pass and an
        epoch of FD/TFD (n = 10) cost ten passes over the memory against PPO's one; over the
        passes every run inside an episode still comes up.
        """
        valid = self.valid_starts(n)
        if n > 1:
            offset = int(torch.randint(n, (1,), generator=generator))
            on_grid = torch.arange(valid.shape[-1], device=valid.device) % n == offset
            valid = valid & on_grid
        starts = valid.nonzero()  # [S, 3]
        if starts.shape[0] == 0:
            return
        order = torch.randperm(starts.shape[0], generator=generator).to(starts.device)
        data = self.stored()
        for chunk in order.tensor_split(min(int(count), starts.shape[0])):
            pick = starts[chunk]
            if n == 1:
                yield self._as_float(data[pick[:, 0], pick[:, 1], pick[:, 2]])
            else:
                steps = pick[:, 2:3] + torch.arange(n, device=pick.device)  # [b, n]
                yield self._as_float(data[pick[:, 0:1], pick[:, 1:2], steps])
