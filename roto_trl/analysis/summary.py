"""The end of a run: ``summary.json``, the plots, the best checkpoint's physical metrics, the report,
and what the run found, printed above where it all is."""

from __future__ import annotations

import json
from pathlib import Path

from omegaconf import DictConfig

from roto_trl.analysis.checkpoint_eval import evaluate_run
from roto_trl.analysis.plots import plot_run
from roto_trl.analysis.report import write_index
from roto_trl.envs.factory import TASKS
from roto_trl.trainers.loggers import read_csv
from roto_trl.trainers.progress import format_duration
from roto_trl.trainers.run_dir import finished_reason
from roto_trl.trainers.state import TrainState


def seconds_named(result: dict[str, float] | None) -> dict[str, float] | None:
    """An evaluation's numbers with its duration ``time`` named with its unit, ``time_s``."""
    if result is None:
        return None
    return {("time_s" if k == "time" else k): v for k, v in result.items()}


def headline_line(label: str, result: dict[str, float] | None, headline: str) -> str:
    """``best evaluation: bounces_per_10s 12.3, return 45.6 (at 1,200,000 frames)``."""
    if result is None:
        return f"{label}: none"
    at = f" (at {int(result['frames']):,} frames)" if "frames" in result else ""
    return f"{label}: {headline} {result[headline]:.4g}, return {result['return_mean']:.4g}{at}"


def write_summary(
    cfg: DictConfig,
    run_dir: Path,
    state: TrainState,
    final_eval: dict[str, float] | None,
    wall: float,
    headline: str,
) -> Path:
    """Write ``<run_dir>/summary.json``: the run's size, clocks and best and final evaluations."""
    summary = {
        "exp_name": cfg.exp_name,
        "task": str(cfg.env.task),
        "seed": int(cfg.seed),
        "frames": state.frames,
        "iterations": state.iteration,
        "wall_time_s": round(wall, 1),
        "frames_per_s": round(state.frames / wall, 1) if wall > 0 else None,
        "eval_time_s": round(state.eval_clock.seconds, 1),
        "eval_share": round(state.eval_clock.share(wall), 4),
        "headline_metric": headline,
        "best_eval": seconds_named(state.best_eval),
        "final_eval": seconds_named(final_eval),
        "run_dir": str(run_dir.resolve()),
    }
    path = run_dir / "summary.json"
    path.write_text(json.dumps(summary, indent=2))
    return path


def finish_run(
    cfg: DictConfig,
    run_dir: Path,
    state: TrainState,
    final_eval: dict[str, float] | None,
    wall: float,
    headline: str,
) -> Path:
    """Write ``summary.json``, the plots, ``eval.json`` (the best checkpoint's physical metrics) and
    ``index.md``; print the best and final evaluations' headline metric, the wall time and where
    the files are. Returns the path of ``summary.json``."""
    path = write_summary(cfg, run_dir, state, final_eval, wall, headline)
    plots = plot_run(run_dir)
    evaluation = evaluate_run(run_dir, "best", episodes=int(cfg.eval.num_envs))
    share = state.eval_clock.share(wall)
    print(headline_line("best evaluation", state.best_eval, headline))
    print(headline_line("final evaluation", final_eval and {"frames": state.frames, **final_eval}, headline))
    speed = state.frames / max(wall, 1e-9)
    print(f"wall time: {format_duration(wall)} ({speed:,.0f} frames/s), evaluation {share:.1%} of it")
    print(f"run directory: {run_dir.resolve()}")
    print(f"plots: {', '.join(str(p.resolve()) for p in plots)}")
    print(f"summary: {path.resolve()}")
    print(f"physical metrics of the best checkpoint: {evaluation.resolve()}")
    print(f"report: {(run_dir / 'index.md').resolve()}")
    return path


def finished_note(cfg: DictConfig, run_dir: Path, state: dict) -> str | None:
    """For a resumed run that has nothing left to train: write the end files it lacks and say so
    in one line; None for a run with frames or time left."""
    reason = finished_reason(cfg, state)
    if reason is None:
        return None
    repaired = repair_end_files(cfg, run_dir, state, TASKS[str(cfg.env.task)].HEADLINE_METRIC)
    done = f"wrote the end files it lacked ({', '.join(repaired)})" if repaired else "it is unchanged"
    return (
        f"resume={run_dir}: nothing to train, {reason}; {done}. Train on with "
        f"resume={run_dir} total_frames=<more> (or a larger time_limit_minutes)"
    )


END_FILES = ("summary.json", "plots/eval.png", "plots/train.png", "eval.json", "index.md")


def repair_end_files(cfg: DictConfig, run_dir: Path, state: dict, headline: str) -> list[str]:
    """Write what a finished run lacks of ``END_FILES`` (a kill after training, before they were
    all written) from its checkpoint ``state`` and logs; returns the names written."""
    run_dir = Path(run_dir)
    missing = [name for name in END_FILES if not (run_dir / name).is_file()]
    if not missing:
        return []
    if "summary.json" in missing:
        progress = TrainState()
        progress.load_state_dict(state)
        rows = read_csv(run_dir / "eval.csv") if (run_dir / "eval.csv").is_file() else {}
        final = {k: v[-1] for k, v in rows.items() if k not in ("frames", "iteration")} if rows else None
        write_summary(cfg, run_dir, progress, final, float(state["wall_time"]), headline)
    if any(name.startswith("plots/") for name in missing):
        plot_run(run_dir)
    if "eval.json" in missing:
        evaluate_run(run_dir, "best", episodes=int(cfg.eval.num_envs))  # rewrites index.md too
    elif "index.md" in missing:
        write_index(run_dir)
    return missing
