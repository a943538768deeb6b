"""A run's checkpoint evaluated on fresh episodes: return, episode metrics and the task's physical
metrics, written as ``eval.json`` (with an optional video) and shown in the run's ``index.md``.
Used by ``evaluate.py``, by ``train.py`` at the end of a run and by the analyses."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path
from typing import Any

import torch
from omegaconf import DictConfig

from roto_trl.analysis.report import write_index
from roto_trl.config import run_config
from roto_trl.envs.rendering import DEFAULT_CAMERA
from roto_trl.modules.distributions import DETERMINISTIC_ACTIONS
from roto_trl.trainers.builders import eval_seed, make_eval_env
from roto_trl.trainers.checkpoint import BEST, LATEST, agent_from_checkpoint, load_checkpoint
from roto_trl.trainers.evaluation import run_episodes
from roto_trl.utils.cli import is_number
from roto_trl.utils.video import write_mp4

NAMED = {"best": BEST, "latest": LATEST}
# "deterministic": the run's agent.deterministic_action
POLICIES = ("deterministic", *DETERMINISTIC_ACTIONS, "stochastic")


def resolve_policy(policy: str, state: dict[str, Any]) -> str:
    """The evaluation policy's name: ``deterministic`` becomes the checkpoint's
    ``agent.deterministic_action``; a ``ValueError`` names the choices for anything unknown."""
    if policy not in POLICIES:
        raise ValueError(f"policy must be one of {list(POLICIES)}, got {policy!r}")
    if policy == "deterministic":
        return str(state["config"].agent.deterministic_action)
    return policy


def checked_noise_scale(noise_scale, policy: str) -> float:
    """``noise_scale`` as a float: > 0, and other than 1 only with ``policy=stochastic`` (the
    deterministic actions have no noise to scale); a one-line ``ValueError`` naming the fix."""
    if not (is_number(noise_scale) and noise_scale > 0):
        raise ValueError(f"noise_scale must be a number > 0 (1: the policy's own std), got {noise_scale!r}")
    if noise_scale != 1 and policy != "stochastic":
        raise ValueError(
            f"noise_scale scales the samples of policy=stochastic, not policy={policy}; add policy=stochastic"
        )
    return float(noise_scale)


def load_run(run_dir: Path, checkpoint: str = "best") -> tuple[DictConfig, dict[str, Any], Path]:
    """A run's config, the chosen checkpoint's state and its path.

    Raises ``FileNotFoundError`` for a missing run or checkpoint and ``ValueError`` for a
    checkpoint of another task or other observations, each naming the fix.
    """
    run_dir = Path(run_dir)
    if not (run_dir / "config.yaml").is_file():
        raise FileNotFoundError(
            f"run={run_dir}: no config.yaml there; give a run directory that train.py wrote"
        )
    path = run_dir / "checkpoints" / NAMED[checkpoint] if checkpoint in NAMED else Path(checkpoint)
    state = load_checkpoint(path)
    try:
        cfg = run_config(run_dir / "config.yaml")
    except ValueError as err:  # the checkpoint holds the run's config too
        print(f"{err}; using the config {path.name} holds", file=sys.stderr)
        cfg = state["config"].copy()
    trained = state["config"].env
    if trained.task != cfg.env.task:
        raise ValueError(
            f"checkpoint {path} was trained on '{trained.task}' but run {run_dir} is '{cfg.env.task}'; "
            "give a checkpoint of this run's task"
        )
    inputs = (list(trained.obs_keys), bool(trained.last_action))
    if inputs != (list(cfg.env.obs_keys), bool(cfg.env.last_action)):
        raise ValueError(
            f"checkpoint {path} sees obs_keys={inputs[0]}, last_action={inputs[1]} but run {run_dir} "
            f"sees obs_keys={list(cfg.env.obs_keys)}, last_action={cfg.env.last_action}; "
            "give a checkpoint of this run's experiment"
        )
    return cfg, state, path


def result_name(checkpoint: str, policy: str = "deterministic", noise_scale: float = 1.0) -> str:
    """The file name of an evaluation's result in the run directory: ``eval.json`` for the best
    checkpoint and the run's own deterministic policy (what training's report shows and the
    analyses read), else named after what was evaluated, e.g. ``eval-latest.json``,
    ``eval-best-stochastic.json``, ``eval-latest-stochastic-std0.5.json``, ``eval-<file stem>.json``."""
    parts = [Path(checkpoint).stem if checkpoint not in NAMED else checkpoint]
    if policy != "deterministic":
        parts.append(policy)
    if noise_scale != 1:
        parts.append(f"std{noise_scale:g}")
    return "eval.json" if parts == ["best"] else f"eval-{'-'.join(parts)}.json"


def evaluate_checkpoint(
    cfg: DictConfig,
    state: dict[str, Any],
    episodes: int,
    seed: int,
    video: bool = False,
    policy: str = "deterministic",
    noise_scale: float = 1.0,
    camera: str = DEFAULT_CAMERA,
) -> tuple[dict[str, Any], list]:
    """Evaluate a checkpoint's policy on ``episodes`` fresh worlds of its task.

    ``policy`` (:data:`POLICIES`): ``deterministic`` (the default and the training evaluations':
    the run's ``agent.deterministic_action``), ``applied_mean`` or ``gaussian_mean`` (that
    deterministic action whatever the run used, see ``roto_trl.modules.distributions``), or
    ``stochastic`` (seeded samples of the policy's Gaussian, clipped by the env as in training).
    ``noise_scale`` (``stochastic`` only): the policy's standard deviation times this factor, so
    that one checkpoint can be read between its controller (-> 0) and its sampled policy (1);
    the scaled log-std keeps training's clamp (``LOG_STD_RANGE``: std at most e^2).

    Returns the result (return mean/std, mean episode length, the encoder's latent rank, episode
    metric means, physical metrics) and, with ``video``, the RGB frames of the first episode
    seen from ``camera``.
    """
    policy = resolve_policy(policy, state)
    noise_scale = checked_noise_scale(noise_scale, policy)
    run_cfg = state["config"].copy()
    run_cfg.device = "cpu"
    if policy in DETERMINISTIC_ACTIONS:
        run_cfg.agent.deterministic_action = policy
    env = make_eval_env(run_cfg, episodes)
    try:
        agent = agent_from_checkpoint({**state, "config": run_cfg}, env)
        if noise_scale != 1:
            with torch.no_grad():  # this evaluation's copy of the policy only
                agent.policy_head.log_std.add_(math.log(noise_scale))
        base = env.base_env
        render = (lambda: base.render(0, camera=camera)) if video else None
        result = run_episodes(env, agent, seed, render=render, stochastic=policy == "stochastic")
        physical = base.physical_metrics(result.final)
    finally:
        env.close()
    summary = {
        "task": cfg.env.task,
        "exp_name": cfg.exp_name,
        "trained_frames": int(state["frames"]),
        "episodes": int(episodes),
        "seed": int(seed),
        "policy": policy,
        **({"noise_scale": noise_scale} if noise_scale != 1 else {}),
        "return_mean": float(result.returns.mean()),
        "return_std": float(result.returns.std(correction=0)),
        "episode_steps_mean": float(result.lengths.double().mean()),
        "latent_rank": result.latent_rank,
        "metrics": {name: float(v.mean()) for name, v in result.final.items()},
        "physical": physical,
    }
    return summary, result.frames


def evaluate_run(
    run_dir: Path,
    checkpoint: str = "best",
    episodes: int | None = None,
    seed: int | None = None,
    video: bool = False,
    out: Path | None = None,
    policy: str = "deterministic",
    noise_scale: float = 1.0,
    camera: str = DEFAULT_CAMERA,
) -> Path:
    """Evaluate one checkpoint of a run, write its result (``result_name``: ``eval.json`` for the best
    checkpoint's default policy) and the video, refresh ``index.md``; returns the result's path."""
    run_dir = Path(run_dir)
    cfg, state, path = load_run(run_dir, checkpoint)
    episodes = int(cfg.eval.num_envs if episodes is None else episodes)
    if episodes < 1:
        raise ValueError(f"episodes must be >= 1, got {episodes}")
    seed = eval_seed(cfg) if seed is None else int(seed)
    summary, frames = evaluate_checkpoint(cfg, state, episodes, seed, video, policy, noise_scale, camera)
    summary = {"run_dir": str(run_dir.resolve()), "checkpoint": str(path.resolve()), **summary}
    if video:
        view = "" if camera == DEFAULT_CAMERA else f"-{camera.removeprefix('roto:')}"
        video_path = run_dir / "videos" / f"eval-{path.stem}-s{seed}{view}.mp4"
        video_path.parent.mkdir(exist_ok=True)
        write_mp4(video_path, frames)
        summary["video"] = str(video_path.resolve())
    out = run_dir / result_name(checkpoint, policy, noise_scale) if out is None else Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(summary, indent=2))
    write_index(run_dir)
    return out
