"""Evaluate a trained run: deterministic episodes in fresh worlds, physical metrics, ``eval.json``.

    python roto_trl/evaluate.py run=runs/bounce_ppo/<run>                       # best checkpoint
    python roto_trl/evaluate.py run=runs/bounce_ppo/<run> checkpoint=latest episodes=200 video=true

Keys (``key=value``, as Hydra's overrides; ``--help`` prints this):
  run          a run directory of ``train.py`` (required)
  checkpoint   best (default), latest, or a ``.pt`` path of a run of the same task
  episodes     evaluation episodes, one world each (default: the run's ``eval.num_envs``)
  seed         the episodes' seed (default: the run's own evaluations', so that
               ``episodes=<eval.num_envs>`` replays them)
  policy       deterministic (default: the run's ``agent.deterministic_action``, as its training
               evaluations) | applied_mean (the mean of the action the env applies) |
               gaussian_mean (the Gaussian's mean: skrl's and the authors') | stochastic (seeded
               samples of its Gaussian, as the agent acts in training)
  noise_scale  with policy=stochastic: the policy's std times this factor (default 1)
  video        true: an mp4 of the first episode in ``<run>/videos/`` (default false)
  camera       the video's camera (default ``roto:side``; Baoding also has ``roto:above``)
  out          where the result goes; default ``<run>/eval.json`` for the best checkpoint's own
               deterministic policy (what training's report and the analyses read), else a file
               named after what is evaluated: ``eval-latest.json``, ``eval-best-stochastic.json``

Physical metrics (per task, :meth:`~roto_trl.envs.robot_env.RobotTaskEnv.physical_metrics`):
Find, seconds to reach each tolerance and the fraction of episodes that reached it; Bounce,
bounces per 10 s; Baoding, complete rotations per 10 s. Afterwards the run's ``index.md``
report is rewritten to show them.
"""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")  # before mujoco is imported; see roto_trl.envs.rendering

import json
import sys
from pathlib import Path
from typing import Any

from roto_trl.analysis.checkpoint_eval import evaluate_run, result_name
from roto_trl.envs.rendering import DEFAULT_CAMERA
from roto_trl.utils.cli import check_int, parse_key_values
from roto_trl.utils.paths import writable_file

DEFAULTS = {
    "run": "???",
    "checkpoint": "best",
    "episodes": None,
    "seed": None,
    "video": False,
    "camera": DEFAULT_CAMERA,
    "out": None,
    "policy": "deterministic",
    "noise_scale": 1.0,
}


def print_result(result: dict[str, Any]) -> None:
    policy = result.get("policy", "deterministic")
    frames = result["trained_frames"]
    if "noise_scale" in result:
        policy = f"{policy} (std x {result['noise_scale']:g})"
    print(f"{result['exp_name']} ({result['task']}), {frames:,} training frames, {policy} policy")
    episodes = result["episodes"]
    print(f"  {'return':<22} {result['return_mean']:.3f} ± {result['return_std']:.3f} ({episodes} episodes)")
    for name, value in result["physical"].items():
        print(f"  {name:<22} {value:.4g}")


def main(argv: list[str] | None = None) -> Path:
    cfg = parse_key_values(
        "evaluate", sys.argv[1:] if argv is None else argv, DEFAULTS, "run=runs/find_ppo/<run>", __doc__
    )
    check_int("evaluate", cfg, "episodes", 1, optional=True)
    check_int("evaluate", cfg, "seed", 0, optional=True)
    if not isinstance(cfg.video, bool):
        raise SystemExit(f"evaluate: video must be true or false, got {cfg.video!r}")
    try:
        default = Path(str(cfg.run)) / result_name(str(cfg.checkpoint), str(cfg.policy), cfg.noise_scale)
        out = Path(str(cfg.out)) if cfg.out is not None else default
        if cfg.out is not None or out.parent.is_dir():  # before the evaluation, not after it
            writable_file(out, "out")
        out = evaluate_run(
            Path(str(cfg.run)),
            str(cfg.checkpoint),
            cfg.episodes,
            cfg.seed,
            bool(cfg.video),
            None if cfg.out is None else Path(str(cfg.out)),
            str(cfg.policy),
            cfg.noise_scale,
            str(cfg.camera),
        )
    except (ValueError, RuntimeError, FileNotFoundError) as err:  # bad input: one line, no traceback
        raise SystemExit(f"evaluate: {err}") from None
    result = json.loads(out.read_text())
    print_result(result)
    if "video" in result:
        print(f"video: {result['video']}")
    print(f"eval: {out.resolve()}")
    return out


if __name__ == "__main__":
    main()
