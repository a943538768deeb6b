"""RoTO-TRL: the Robot Tactile Olympiad on MuJoCo and TorchRL.

``import roto_trl`` registers the Gymnasium ids and nothing else; ``make_env`` and ``TASKS`` load
the simulator on first use, so a program may still set ``MUJOCO_GL`` after importing the package.

It also sets ``OMP_WAIT_POLICY=PASSIVE`` (unless set) for programs that import it before torch:
torch's OpenMP threads then sleep between operations instead of spinning, and so leave the cores
to MuJoCo's physics threads. With spinning threads (the default) an env step with 2 torch threads
took twice as long as with 1 on 2 cores, and a PPO minibatch update several times as long on a
busy machine (``benchmarks/train_throughput.py``). It must be set before torch loads OpenMP.
"""

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from roto_trl.envs.registration import register_envs

__version__ = "0.1.0"
__all__ = ["TASKS", "make_env"]

register_envs()  # RoTO/Find-v0, RoTO/Bounce-v0, RoTO/Baoding-v0 for gymnasium.make / make_vec


def __getattr__(name: str):
    if name in __all__:
        from roto_trl.envs import factory

        return getattr(factory, name)
    raise AttributeError(f"module 'roto_trl' has no attribute {name!r}")
