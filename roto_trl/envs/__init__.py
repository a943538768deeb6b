"""RoTO tasks as batched TorchRL environments."""

from roto_trl.envs.baoding import BaodingEnv
from roto_trl.envs.bounce import BounceEnv
from roto_trl.envs.factory import TASKS, make_env, task_config
from roto_trl.envs.find import FindEnv

__all__ = ["TASKS", "BaodingEnv", "BounceEnv", "FindEnv", "make_env", "task_config"]
