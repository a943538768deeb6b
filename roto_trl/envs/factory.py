"""``make_env``: the one place where a task name and overrides become a ready TorchRL env."""

from __future__ import annotations

import dataclasses

import torch
from torchrl.envs import CatFrames, CatTensors, Compose, TransformedEnv

from roto_trl.envs.baoding import BaodingEnv
from roto_trl.envs.bounce import BounceEnv
from roto_trl.envs.find import FindEnv
from roto_trl.transforms import BinariseContacts, LastAction, ScaleProprioception

# task name -> env class (its CONFIG, SENSORS, VEL_SCALE and PROP_EXTRA say the rest)
TASKS = {"find": FindEnv, "bounce": BounceEnv, "baoding": BaodingEnv}
PROP_PARTS = ("last_action", "joint_pos", "joint_vel")  # then the task's PROP_EXTRA


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
        config.reward_scales.update({k: float(v) for k, v in scales.items()})
    return config


def make_env(
    task: str,
    num_envs: int,
    *,
    seed: int = 0,
    device: str | torch.device = "cpu",
    last_action: bool = True,
    **overrides,
) -> TransformedEnv:
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
        A ``TransformedEnv`` whose policy inputs are ``"prop"`` (float32 ``[N, k*P]``: last action,
        scaled joint angles and velocities, oldest reading first) and ``"tactile"`` (float32 0/1
        ``[N, k*T]``), with ``"contact_force"``, ``"state"``, the task's episode metric and
        ``"reward_terms"`` alongside. The base env is ``env.base_env`` (``.mj_model``).
    """
    if not isinstance(num_envs, int) or num_envs < 1:
        raise ValueError(f"num_envs must be a positive integer, got {num_envs!r}")
    config = task_config(task, **overrides)
    base = TASKS[task](num_envs, config, seed=seed, device=device)
    parts = PROP_PARTS if last_action else PROP_PARTS[1:]
    return TransformedEnv(
        base,
        Compose(
            *([LastAction(base.n_actions)] if last_action else []),
            ScaleProprioception(base.joint_low, base.joint_high, base.VEL_SCALE),
            CatTensors([*parts, *base.PROP_EXTRA], out_key="prop", sort=False),
            BinariseContacts(config.contact_threshold),
            CatFrames(N=config.history, dim=-1, in_keys=["prop", "tactile"], padding="same"),
        ),
    )
