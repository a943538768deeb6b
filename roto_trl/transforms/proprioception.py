"""Proprioception as the policy sees it: scaled joint readings and the last action."""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from torchrl.data import Bounded, Composite
from torchrl.envs.transforms import Transform


class ScaleProprioception(Transform):
    """Joint angles to [-1, 1] by their limits and joint velocities times ``vel_scale``, in place.

    Args:
        low, high: ``[J]`` joint limits (the env's ``joint_low`` / ``joint_high``).
        vel_scale: factor on the joint velocities (0.2 for the Shadow Hand, 0.33 for the Franka).
        pos_key, vel_key: the ``[*B, J]`` entries to scale.
    """

    def __init__(
        self,
        low: torch.Tensor,
        high: torch.Tensor,
        vel_scale: float,
        pos_key: str = "joint_pos",
        vel_key: str = "joint_vel",
    ) -> None:
        low, high = torch.as_tensor(low, dtype=torch.float32), torch.as_tensor(high, dtype=torch.float32)
        if low.shape != high.shape or low.ndim != 1 or not bool((high > low).all()):
            raise ValueError("joint limits must be two 1-D tensors of one size with high > low")
        super().__init__(in_keys=[pos_key, vel_key], out_keys=[pos_key, vel_key])
        self.register_buffer("centre", (high + low) / 2)
        self.register_buffer("half_range", (high - low) / 2)
        self.vel_scale = float(vel_scale)

    def _call(self, next_tensordict: TensorDictBase) -> TensorDictBase:
        pos_key, vel_key = self.in_keys
        next_tensordict.set(pos_key, (next_tensordict.get(pos_key) - self.centre) / self.half_range)
        return next_tensordict.set(vel_key, next_tensordict.get(vel_key) * self.vel_scale)

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase):
        return self._call(tensordict_reset)


class LastAction(Transform):
    """Add the action applied in the previous step, clipped to [-1, 1], as ``out_key``.

    The transform keeps the last action of every env itself (as ``CatFrames`` keeps its frames),
    so the entry is right even when later transforms drop it from the tensordict. It is zero at
    the start of an episode, for exactly the envs whose ``"_reset"`` flag is set.

    Args:
        n_actions: size of the action vector.
        action_key: where the policy writes its action.
        out_key: observation entry, ``[*B, n_actions]`` float32.
    """

    def __init__(self, n_actions: int, action_key: str = "action", out_key: str = "last_action"):
        super().__init__(in_keys=[], out_keys=[out_key])
        self.n_actions = int(n_actions)
        self.action_key = action_key
        self._last: torch.Tensor | None = None

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        self._last = tensordict.get(self.action_key).to(torch.float32).clamp(-1.0, 1.0)
        return next_tensordict.set(self.out_keys[0], self._last)

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase):
        reset = None if tensordict is None else tensordict.get("_reset", None)
        shape = (*tensordict_reset.batch_size, self.n_actions)
        if self._last is None or reset is None or self._last.shape != shape:
            self._last = torch.zeros(shape, device=tensordict_reset.device)
        else:
            self._last = self._last.masked_fill(reset.reshape(*shape[:-1], 1), 0.0)
        return tensordict_reset.set(self.out_keys[0], self._last)

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        observation_spec[self.out_keys[0]] = Bounded(
            low=-1.0,
            high=1.0,
            shape=(*observation_spec.shape, self.n_actions),
            dtype=torch.float32,
            device=observation_spec.device,
        )
        return observation_spec
