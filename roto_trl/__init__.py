"""RoTO-TRL: the Robot Tactile Olympiad on MuJoCo and TorchRL.

``import roto_trl`` registers the Gymnasium ids and sets OpenMP's defaults (below), nothing else;
``make_env`` and ``TASKS`` load the simulator on first use, so a program may still set
``MUJOCO_GL`` after importing the package.

The OpenMP defaults say how torch's OpenMP threads wait between operations, for programs that
import it before torch (each only where the variable is unset; OpenMP reads them when torch loads it):

- ``OMP_WAIT_POLICY=PASSIVE``: threads sleep instead of spinning for libgomp's default 300,000
  spins after every operation, which would leave MuJoCo's physics threads without cores;
- ``GOMP_SPINCOUNT=10000``: but to sleep at once costs a wake-up of every thread at every
  operation; 10,000 spins bridge the gaps between the operations of an update or a policy
  forward and are over long before a physics step ends.

What each costs and saves: docs/throughput.md (``benchmarks/train_throughput.py`` measures it).
"""

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
os.environ.setdefault("GOMP_SPINCOUNT", "10000")

from roto_trl.envs.registration import register_envs

__version__ = "0.1.0"
__all__ = ["TASKS", "make_env"]

register_envs()  # RoTO/Find-v0, RoTO/Bounce-v0, RoTO/Baoding-v0 for gymnasium.make / make_vec


def __getattr__(name: str):
    if name in __all__:
        from roto_trl.envs import factory

        return getattr(factory, name)
    raise AttributeError(f"module 'roto_trl' has no attribute {name!r}")
