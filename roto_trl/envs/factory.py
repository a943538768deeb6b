"""``make_env``: the one place where a task name and overrides become a ready TorchRL env."""

from __future__ import annotations

import dataclasses
import os

import torch
from torchrl.envs import CatFrames, CatTensors, Compose

from roto_trl.envs.baoding import BaodingEnv
from roto_trl.envs.bounce import BounceEnv
from roto_trl.envs.find import FindEnv
from roto_trl.envs.one_thread import OneThreadTransformedEnv
from roto_trl.envs.robot_env import check_reward_scales
from roto_trl.transforms import BinariseContacts, LastAction, ScaleProprioception

# task name -> env class (its CONFIG, SENSORS, VEL_SCALE and PROP_EXTRA say the rest)
TASKS = {"find": FindEnv, "bounce": BounceEnv, "baoding": BaodingEnv}
PROP_PARTS = ("last_action", "joint_pos", "joint_vel")  # then the task's PROP_EXTRA
# Memory of one world, measured after two steps of step_and_maybe_reset (24 KiB Bounce/Baoding
# at history 4, 28 KiB Find at history 16) and rounded up: a fixed part plus one per history step.
WORLD_BYTES, HISTORY_BYTES = 16 * 1024, 2 * 1024


def task_config(task: str, **overrides):
    """The task's config with ``overrides`` applied, or a one-line error naming what is wrong."""
    if task not in TASKS:
        raise ValueError(f"unknown task {task!r}; choose one of {sorted(TASKS)}")
    config_cls = TASKS[task].CONFIG
    valid = [f.name for f in dataclasses.fields(config_cls)]
    unknown = sorted(set(overrides) - set(valid))
    if unknown:
        raise ValueError(f"unknown override(s) {unknown} for task {task!r}; valid: {valid}")
    scales = overrides.pop("reward_scales", None)
    config = config_cls(**overrides)
    if scales is not None:
        bad = sorted(set(scales) - set(config.reward_scales))
        if bad:
            raise ValueError(
                f"unknown reward term(s) {bad} for task {task!r}; terms: {sorted(config.reward_scales)}"
            )
        check_reward_scales(scales)
        config.reward_scales.update({term: float(value) for term, value in scales.items()})
    return config


def available_memory() -> int | None:
    """Bytes of memory available to new allocations (Linux ``MemAvailable``), None if unknown."""
    try:
        with open("/proc/meminfo") as handle:
            for line in handle:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError):
        return None


def check_memory(task: str, num_envs: int, history: int) -> None:
    """Refuse, before allocating, a batch that would not fit in the available memory."""
    need = num_envs * (WORLD_BYTES + history * HISTORY_BYTES)
    available = available_memory()
    if available is not None and need > available:
        gib = 2**30
        raise ValueError(
            f"make_env({task!r}, {num_envs:,}) needs about {need / gib:.1f} GiB "
            f"({(WORLD_BYTES + history * HISTORY_BYTES) // 1024} KiB a world) but this machine has "
            f"{available / gib:.1f} GiB available; use fewer worlds"
        )


def make_env(
    task: str,
    num_envs: int,
    *,
    seed: int = 0,
    device: str | torch.device = "cpu",
    last_action: bool = True,
    **overrides,
) -> OneThreadTransformedEnv:
    """Build a batched RoTO task with the agent's observation pipeline.

    Args:
        task: ``"find"``, ``"bounce"`` or ``"baoding"``.
        num_envs: worlds stepped together; the env's batch size is ``[num_envs]``.
        seed: seed of the reset randomisation (same seed and actions give the same observations).
        device: where the returned tensors live (physics runs on the CPU).
        last_action: put the previous action at the front of each ``prop`` reading (the paper's
            default; ``False`` for the proprioception-without-last-action ablation).
        **overrides: fields of the task's config (``FindConfig``, ``ShadowTaskConfig``), e.g.
            ``action_ema=0.5``, ``contact_threshold=0.1``, ``reward_scales={"air": 0.0}``.

    Returns:
        A ``TransformedEnv`` (``OneThreadTransformedEnv``: its steps and resets run torch on one
        thread, which makes their small operations cheaper) whose policy inputs are ``"prop"``
        (float32 ``[N, k*P]``: last action, scaled joint angles and velocities, oldest reading
        first) and ``"tactile"`` (float32 0/1 ``[N, k*T]``), with ``"contact_force"``,
        ``"state"``, the task's episode metric and ``"reward_terms"`` alongside. The base env is
        ``env.base_env`` (``.mj_model``).
    """
    if isinstance(num_envs, bool) or not isinstance(num_envs, int) or num_envs < 1:
        raise ValueError(f"num_envs must be a positive integer, got {num_envs!r}")
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ValueError(f"seed must be an integer >= 0, got {seed!r}")
    config = task_config(task, **overrides)
    check_memory(task, num_envs, config.history)
    base = TASKS[task](num_envs, config, seed=seed, device=device)
    parts = PROP_PARTS if last_action else PROP_PARTS[1:]
    return OneThreadTransformedEnv(
        base,
        Compose(
            *([LastAction(base.n_actions)] if last_action else []),
            ScaleProprioception(base.joint_low, base.joint_high, base.VEL_SCALE),
            CatTensors([*parts, *base.PROP_EXTRA], out_key="prop", sort=False),
            BinariseContacts(config.contact_threshold),
            CatFrames(N=config.history, dim=-1, in_keys=["prop", "tactile"], padding="same"),
        ),
    )
