"""Binary touch from per-sensor contact forces."""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from torchrl.data import Binary, Composite
from torchrl.envs.transforms import Transform


class BinariseContacts(Transform):
    """Write ``out_key`` = 1.0 where the force at ``in_key`` exceeds ``threshold``, else 0.0.

    The raw forces stay under ``in_key`` for users who want continuous touch.

    Args:
        threshold: force in newtons; 0.0 (default) makes any contact read 1.
        in_key: per-sensor force magnitudes, ``[*B, S]``.
        out_key: binary contacts, ``[*B, S]`` float32 in {0, 1}.
    """

    def __init__(
        self, threshold: float = 0.0, in_key: str = "contact_force", out_key: str = "tactile"
    ) -> None:
        if not threshold >= 0.0:
            raise ValueError(f"contact threshold must be a force >= 0 N, got {threshold}")
        super().__init__(in_keys=[in_key], out_keys=[out_key])
        self.threshold = float(threshold)

    def _call(self, next_tensordict: TensorDictBase) -> TensorDictBase:
        force = next_tensordict.get(self.in_keys[0])
        return next_tensordict.set(self.out_keys[0], (force > self.threshold).to(torch.float32))

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase):
        return self._call(tensordict_reset)

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        src = observation_spec[self.in_keys[0]]
        observation_spec[self.out_keys[0]] = Binary(
            n=src.shape[-1], shape=src.shape, dtype=torch.float32, device=src.device
        )
        return observation_spec
