"""RoTO-TRL: the Robot Tactile Olympiad on MuJoCo and TorchRL."""

from roto_trl.envs import TASKS, make_env

__all__ = ["TASKS", "make_env"]
__version__ = "0.1.0"
