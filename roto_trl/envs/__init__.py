"""RoTO tasks as batched TorchRL environments, and their Gymnasium interface.

The task classes and ``make_env`` load on first use (``__getattr__``), so that ``import roto_trl``
(which registers the Gymnasium ids from ``registration``) does not import MuJoCo or torch.
"""

from importlib import import_module

_EXPORTS = {
    "TASKS": "factory",
    "make_env": "factory",
    "task_config": "factory",
    "BaodingEnv": "baoding",
    "BounceEnv": "bounce",
    "FindEnv": "find",
}
__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name in _EXPORTS:
        return getattr(import_module(f"roto_trl.envs.{_EXPORTS[name]}"), name)
    raise AttributeError(f"module 'roto_trl.envs' has no attribute {name!r}")
