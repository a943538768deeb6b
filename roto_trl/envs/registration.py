"""Gymnasium ids of the RoTO tasks, registered on ``import roto_trl``.

This module imports only gymnasium: registering must not load MuJoCo or torch, so that
``import roto_trl`` stays cheap and programs can still choose MuJoCo's GL backend afterwards.
"""

from __future__ import annotations

import gymnasium

ENV_IDS = {"find": "RoTO/Find-v0", "bounce": "RoTO/Bounce-v0", "baoding": "RoTO/Baoding-v0"}


def register_envs() -> None:
    """Register ``RoTO/<Task>-v0`` for ``gymnasium.make`` and ``gymnasium.make_vec`` (idempotent)."""
    for task, env_id in ENV_IDS.items():
        if env_id not in gymnasium.registry:
            gymnasium.register(
                id=env_id,
                entry_point="roto_trl.envs.gymnasium_env:RoToEnv",
                vector_entry_point="roto_trl.envs.gymnasium_env:RoToVectorEnv",
                kwargs={"task": task},
            )
