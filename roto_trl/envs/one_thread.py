"""A ``TransformedEnv`` whose steps and resets run torch's operations on one thread.

An env step's tensors are small (a few hundred worlds times tens of numbers), so each torch
operation costs its call overhead, not its arithmetic. With more than one torch thread the
larger ones (``CatFrames``' roll, clones) hand work to torch's OpenMP team, whose threads have
gone to sleep while MuJoCo's own threads ran the physics: waking them costs more than the
operation. Measured on the 2-core machine (256 worlds, two physics threads, random actions,
``benchmarks/env_throughput.py``, alternating runs): with two torch threads Bounce's env ran at
0.71-0.72 of raw ``mujoco.rollout``, with one at 0.79-0.81; Find 0.55 and 0.69-0.73. The
physics keeps its own threads (``num_threads`` of the task config), and the policy and the
update keep torch's: the thread count is lowered only for the duration of each call and
restored after it.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import torch
from tensordict import TensorDictBase
from torchrl.envs import TransformedEnv


@contextlib.contextmanager
def one_torch_thread() -> Iterator[None]:
    """Run the body with ``torch.set_num_threads(1)``; restore the caller's count after it."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(before)


class OneThreadTransformedEnv(TransformedEnv):
    """``TransformedEnv`` whose ``step``, ``reset`` and ``step_and_maybe_reset`` use one torch thread.

    Everything else (specs, transforms, ``rollout``, whose policy calls run between steps with the
    caller's threads) is ``TransformedEnv``'s. Add transforms with ``append_transform``, which
    keeps this class; wrapped in another ``TransformedEnv`` the outer env calls this one's private
    ``_step`` and runs with the caller's threads (the same results, only slower).
    """

    def step(self, tensordict: TensorDictBase) -> TensorDictBase:
        with one_torch_thread():
            return super().step(tensordict)

    def reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        with one_torch_thread():
            return super().reset(tensordict, **kwargs)

    def step_and_maybe_reset(self, tensordict: TensorDictBase) -> tuple[TensorDictBase, TensorDictBase]:
        with one_torch_thread():
            return super().step_and_maybe_reset(tensordict)
