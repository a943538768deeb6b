"""Record one episode of a task as an mp4, the active contact sensors drawn lit.

    python -m roto_trl.record task=bounce                          # random actions
    python -m roto_trl.record policy=runs/find_ppo/<run>/checkpoints/best.pt   # the run's task
    python -m roto_trl.record task=baoding seed=3 out=baoding.mp4 width=480 height=360

Keys (``key=value``, as Hydra's overrides; ``--help`` prints this):
  task       find | bounce | baoding; required with random actions, with a checkpoint the run's
  policy     random (default) or a training checkpoint (``.pt``; its deterministic policy)
  seed       the episode's reset seed (default 0)
  out        the mp4 to write (default ``runs/videos/<task>-<policy>-<time>.mp4``)
  camera     a camera of the scene (default ``roto:side``)
  width, height   the frames' size in pixels (default 640 x 480; even numbers)
  max_steps  stop after this many steps (default: the whole episode)
  env.<field>=    any ``make_env`` override (with a checkpoint, on top of the run's own settings)

Frames are rendered offscreen; on a machine without a display this script uses
``MUJOCO_GL=egl`` unless ``MUJOCO_GL`` is already set.
"""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")  # before mujoco is imported; see roto_trl.envs.rendering

import sys
from datetime import datetime
from pathlib import Path

import roto_trl  # noqa: F401  first, before torch loads: sets how its OpenMP threads wait (roto_trl/__init__.py)

# isort: split
import torch
from omegaconf import DictConfig, OmegaConf

from roto_trl.envs.factory import TASKS, make_env
from roto_trl.envs.rendering import DEFAULT_CAMERA
from roto_trl.trainers.builders import make_task_env
from roto_trl.trainers.checkpoint import load_checkpoint, policy_from_checkpoint
from roto_trl.utils.cli import check_int, parse_key_values
from roto_trl.utils.paths import writable_file
from roto_trl.utils.video import write_mp4

DEFAULTS = {
    "task": None,
    "policy": "random",
    "seed": 0,
    "out": None,
    "camera": DEFAULT_CAMERA,
    "width": 640,
    "height": 480,
    "max_steps": None,
    "env": {},
}


def parse_args(argv: list[str]) -> DictConfig:
    """``key=value`` arguments over ``DEFAULTS``, with one-line errors for unknown or missing keys."""
    cfg = parse_key_values("record", argv, DEFAULTS, "task=bounce policy=random", __doc__)
    if cfg.task is None and cfg.policy == "random":
        raise SystemExit(f"record: give task=<{'|'.join(sorted(TASKS))}> for random actions")
    if cfg.task is not None and cfg.task not in TASKS:
        raise SystemExit(f"record: give task=<{'|'.join(sorted(TASKS))}>, got {cfg.task!r}")
    for key in ("width", "height"):  # H.264 frames have even sides: 2 pixels at least
        check_int("record", cfg, key, 2)
    check_int("record", cfg, "max_steps", 1, optional=True)
    check_int("record", cfg, "seed", 0)
    if cfg.out is not None:
        out = Path(str(cfg.out))
        try:
            writable_file(out, "out")
        except ValueError as err:
            raise SystemExit(f"record: {err}") from None
        if out.suffix.lower() != ".mp4":
            raise SystemExit(f"record: out={out} must name an .mp4 file")
    return cfg


def make_env_and_policy(cfg: DictConfig):
    """The one-world env and the policy: random actions, or a checkpoint's deterministic policy.

    With a checkpoint the env is built from the run's own settings (task, overrides, inputs), so
    the policy sees what it was trained on; ``task`` must name the same task.
    """
    if cfg.policy == "random":
        env = make_env(cfg.task, 1, seed=int(cfg.seed), **OmegaConf.to_container(cfg.env))
        gen = torch.Generator().manual_seed(int(cfg.seed))
        n_actions = env.base_env.n_actions
        return env, lambda td: torch.rand(1, n_actions, generator=gen) * 2 - 1
    state = load_checkpoint(Path(str(cfg.policy)))
    run_cfg = state["config"].copy()
    if cfg.task is None:
        cfg.task = str(run_cfg.env.task)
    if run_cfg.env.task != cfg.task:
        raise ValueError(f"the checkpoint was trained on '{run_cfg.env.task}', not task={cfg.task}")
    run_cfg.device = "cpu"
    run_cfg.env.overrides = OmegaConf.merge(run_cfg.env.overrides, cfg.env)
    env = make_task_env(run_cfg, 1, int(cfg.seed))
    return env, policy_from_checkpoint(state, env)


def record(cfg: DictConfig) -> Path:
    """Run one episode of ``cfg.task`` with ``cfg.policy``, write it as an mp4, return its path."""
    env, policy = make_env_and_policy(cfg)
    base = env.base_env
    steps = base.max_episode_steps if cfg.max_steps is None else int(cfg.max_steps)
    render = {"camera": cfg.camera, "width": int(cfg.width), "height": int(cfg.height)}
    td = env.reset()
    frames = [base.render(0, **render)]
    ret = 0.0
    with torch.no_grad():
        for _ in range(steps):
            td = env.step(td.set("action", policy(td)))["next"]
            frames.append(base.render(0, **render))
            ret += float(td["reward"])
            if bool(td["done"].any()):
                break
    metrics = {k: td[k][0].tolist() for k in base.METRICS}
    env.close()
    if cfg.out is None:
        name = "random" if cfg.policy == "random" else Path(str(cfg.policy)).stem
        out = Path("runs") / "videos" / f"{cfg.task}-{name}-{datetime.now():%Y%m%d-%H%M%S}.mp4"
    else:
        out = Path(str(cfg.out))
    out.parent.mkdir(parents=True, exist_ok=True)
    write_mp4(out, frames)
    summary = ", ".join(f"{k} {v}" for k, v in metrics.items())
    print(f"{cfg.task}: {len(frames) - 1} steps, return {ret:.2f}, {summary}")
    print(f"video: {out.resolve()}")
    return out


def main(argv: list[str] | None = None) -> Path:
    cfg = parse_args(sys.argv[1:] if argv is None else argv)
    try:
        return record(cfg)
    except (ValueError, RuntimeError, FileNotFoundError) as err:  # bad input: one line, no traceback
        raise SystemExit(f"record: {err}") from None


if __name__ == "__main__":
    main()
