"""Evaluate a trained run: deterministic episodes in fresh worlds, physical metrics, ``eval.json``.

    python roto_trl/evaluate.py run=runs/bounce_ppo/<run>                       # best checkpoint
    python roto_trl/evaluate.py run=runs/bounce_ppo/<run> checkpoint=latest episodes=200 video=true

Keys (``key=value``): ``run`` (required, a run directory of ``train.py``), ``checkpoint``
(``best``, ``latest`` or a ``.pt`` path of a run of the same task), ``episodes`` (default: the
run's ``eval.num_envs``; one world per episode), ``seed`` (default: the seed of the run's own
evaluations, so ``episodes=<eval.num_envs>`` replays them), ``video`` (``true``: an mp4 of the
first episode in ``<run>/videos/``), ``out`` (default ``<run>/eval.json``).

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

from omegaconf import DictConfig, OmegaConf

from roto_trl.builders import eval_seed, make_eval_env
from roto_trl.checkpoint import BEST, LATEST, agent_from_checkpoint, load_checkpoint
from roto_trl.cli import parse_key_values
from roto_trl.evaluation import run_episodes
from roto_trl.record import write_mp4
from roto_trl.report import write_index

DEFAULTS = {"run": "???", "checkpoint": "best", "episodes": None, "seed": None, "video": False, "out": None}
NAMED = {"best": BEST, "latest": LATEST}


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
    cfg = OmegaConf.load(run_dir / "config.yaml")
    path = run_dir / "checkpoints" / NAMED[checkpoint] if checkpoint in NAMED else Path(checkpoint)
    state = load_checkpoint(path)
    trained = state["config"]["env"]
    if trained["task"] != cfg.env.task:
        raise ValueError(
            f"checkpoint {path} was trained on {trained['task']!r} but run {run_dir} is {cfg.env.task!r}; "
            "give a checkpoint of this run's task"
        )
    inputs = (list(trained["obs_keys"]), bool(trained["last_action"]))
    if inputs != (list(cfg.env.obs_keys), bool(cfg.env.last_action)):
        raise ValueError(
            f"checkpoint {path} sees obs_keys={inputs[0]}, last_action={inputs[1]} but run {run_dir} "
            f"sees obs_keys={list(cfg.env.obs_keys)}, last_action={cfg.env.last_action}; "
            "give a checkpoint of this run's experiment"
        )
    return cfg, state, path


def evaluate_checkpoint(
    cfg: DictConfig, state: dict[str, Any], episodes: int, seed: int, video: bool = False
) -> tuple[dict[str, Any], list]:
    """Evaluate a checkpoint's deterministic policy on ``episodes`` fresh worlds of its task.

    Returns the result (return mean/std, mean episode length, episode metric means, physical
    metrics) and, with ``video``, the RGB frames of the first episode.
    """
    run_cfg = OmegaConf.create(state["config"])
    run_cfg.device = "cpu"
    env = make_eval_env(run_cfg, episodes)
    try:
        agent = agent_from_checkpoint(state, env)
        base = env.base_env
        result = run_episodes(env, agent, seed, render=(lambda: base.render(0)) if video else None)
        physical = base.physical_metrics(result.final)
    finally:
        env.close()
    summary = {
        "task": cfg.env.task,
        "exp_name": cfg.exp_name,
        "trained_frames": int(state["frames"]),
        "episodes": int(episodes),
        "seed": int(seed),
        "return_mean": float(result.returns.mean()),
        "return_std": float(result.returns.std(correction=0)),
        "episode_steps_mean": float(result.lengths.double().mean()),
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
) -> Path:
    """Evaluate one checkpoint of a run, write ``eval.json`` (and the video), refresh ``index.md``."""
    run_dir = Path(run_dir)
    cfg, state, path = load_run(run_dir, checkpoint)
    episodes = int(cfg.eval.num_envs if episodes is None else episodes)
    if episodes < 1:
        raise ValueError(f"episodes must be >= 1, got {episodes}")
    seed = eval_seed(cfg) if seed is None else int(seed)
    summary, frames = evaluate_checkpoint(cfg, state, episodes, seed, video)
    summary = {"run_dir": str(run_dir.resolve()), "checkpoint": str(path.resolve()), **summary}
    if video:
        video_path = run_dir / "videos" / f"eval-{path.stem}-s{seed}.mp4"
        video_path.parent.mkdir(exist_ok=True)
        write_mp4(video_path, frames)
        summary["video"] = str(video_path.resolve())
    out = run_dir / "eval.json" if out is None else Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(summary, indent=2))
    write_index(run_dir)
    return out


def print_result(result: dict[str, Any]) -> None:
    print(f"{result['exp_name']} ({result['task']}), {result['trained_frames']:,} training frames")
    episodes = result["episodes"]
    print(f"  {'return':<22} {result['return_mean']:.3f} ± {result['return_std']:.3f} ({episodes} episodes)")
    for name, value in result["physical"].items():
        print(f"  {name:<22} {value:.4g}")


def main(argv: list[str] | None = None) -> Path:
    cfg = parse_key_values(
        "evaluate", sys.argv[1:] if argv is None else argv, DEFAULTS, "run=runs/find_ppo/<run>"
    )
    try:
        out = evaluate_run(
            Path(str(cfg.run)),
            str(cfg.checkpoint),
            cfg.episodes,
            cfg.seed,
            bool(cfg.video),
            None if cfg.out is None else Path(str(cfg.out)),
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
