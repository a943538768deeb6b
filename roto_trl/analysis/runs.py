"""Finding run directories and aggregating their logs across seeds."""

from __future__ import annotations

import glob
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from omegaconf import OmegaConf

from roto_trl.trainers.loggers import read_csv


@dataclass
class Run:
    """A run directory of ``train.py`` and what it was."""

    path: Path
    exp_name: str
    task: str
    seed: int
    config: dict

    @property
    def label(self) -> str:
        return f"{self.exp_name}/{self.path.name}"


def find_runs(patterns: list[str]) -> list[Run]:
    """Run directories matching ``patterns`` (paths or globs), in sorted order.

    Raises ``ValueError`` naming the patterns when nothing matches, or a match is not a run.
    """
    paths: list[Path] = []
    for pattern in patterns:
        # a glob matches run directories only (a sweep directory also holds multirun.yaml)
        matched = sorted(Path(p) for p in glob.glob(pattern) if Path(p).is_dir()) or (
            [Path(pattern)] if Path(pattern).exists() else []
        )
        if not matched:
            raise ValueError(f"no run directories match {pattern!r}; give run directories or a quoted glob")
        paths += [p for p in matched if p not in paths]
    runs = []
    for path in paths:
        if not (path / "config.yaml").is_file():
            raise ValueError(f"{path} is not a run directory of train.py (no config.yaml)")
        cfg = OmegaConf.to_container(OmegaConf.load(path / "config.yaml"))
        runs.append(Run(path, cfg["exp_name"], cfg["env"]["task"], int(cfg["seed"]), cfg))
    return runs


def run_csv(run: Run, name: str, needs: str) -> dict[str, list[float]]:
    """The columns of one of the run's CSV files, or a ``ValueError`` saying what ``needs`` it."""
    path = run.path / name
    if not path.is_file():
        raise ValueError(f"{run.path} has no {name}; {needs}")
    return read_csv(path)


def one_task(runs: list[Run], command: str) -> str:
    """The task all ``runs`` share, or a ``ValueError`` listing the mix."""
    tasks = sorted({r.task for r in runs})
    if len(tasks) != 1:
        raise ValueError(f"{command} compares runs of one task; these mix {tasks}: give runs of one task")
    return tasks[0]


def by_experiment(runs: list[Run]) -> dict[str, list[Run]]:
    """Runs grouped by ``exp_name``, experiments in first-seen order."""
    groups: dict[str, list[Run]] = {}
    for run in runs:
        groups.setdefault(run.exp_name, []).append(run)
    return groups


@dataclass
class Curve:
    """Evaluation return of one experiment across seeds on a common grid of frames or minutes."""

    x: np.ndarray  # [F] frames, or minutes of training wall time
    mean: np.ndarray  # [F]
    std: np.ndarray  # [F]
    seeds: int


def eval_minutes(run: Run, frames: np.ndarray) -> np.ndarray:
    """Training wall time (minutes) at which the run had collected ``frames``, from ``train.csv``."""
    train = read_csv(run.path / "train.csv")
    at = np.concatenate([[0.0], train["frames"]])
    wall = np.concatenate([[0.0], train["wall_time"]]) / 60.0
    return np.interp(frames, at, wall)


def learning_curve(runs: list[Run], x: str = "frames", metric: str = "return_mean") -> Curve:
    """Mean ± 1 std (across runs) of an evaluation ``metric`` (an ``eval.csv`` column) against
    frames or wall time.

    ``x`` is ``"frames"`` or ``"minutes"`` (training wall time, its evaluations included, for
    comparisons at an equal time budget). Each run's ``eval.csv`` is linearly interpolated onto
    the union of all runs' evaluation points, up to the shortest run's last evaluation, so every
    point averages every seed.
    """
    series = []
    for run in runs:
        ev = run_csv(run, "eval.csv", "curves need runs that have evaluated at least once")
        if metric not in ev:
            raise ValueError(f"{run.path}/eval.csv has no column {metric!r}; columns: {sorted(ev)}")
        frames = np.asarray(ev["frames"])
        series.append((frames if x == "frames" else eval_minutes(run, frames), np.asarray(ev[metric])))
    end = min(points[-1] for points, _ in series)
    grid = np.unique(np.concatenate([points[points <= end] for points, _ in series]))
    values = np.stack([np.interp(grid, points, returns) for points, returns in series])
    return Curve(grid, values.mean(0), values.std(0), len(runs))


def read_json(path: Path) -> dict | None:
    """A run's JSON file (``summary.json``, ``eval.json``, ...), or None when it is not there."""
    return json.loads(path.read_text()) if path.is_file() else None


def physical_metrics(runs: list[Run]) -> dict[str, np.ndarray]:
    """``metric -> [seeds]`` from each run's ``eval.json`` (``roto_trl/evaluate.py``), with the
    evaluation return as ``return``; runs not yet evaluated raise a ``ValueError`` naming the fix."""
    values: dict[str, list[float]] = {}
    for run in runs:
        result = read_json(run.path / "eval.json")
        if result is None:
            raise ValueError(f"{run.path} has no eval.json; run: python roto_trl/evaluate.py run={run.path}")
        for name, value in {"return": result["return_mean"], **result["physical"]}.items():
            values.setdefault(name, []).append(float(value))
    return {name: np.asarray(v) for name, v in values.items()}


def headline_of(run_dir: Path) -> str | None:
    """The headline metric of the run's task (its ``config.yaml``), or None when unknown."""
    from roto_trl.envs.factory import TASKS  # loads the simulator: only when asked

    path = Path(run_dir) / "config.yaml"
    task = str(OmegaConf.load(path).env.task) if path.is_file() else None
    return TASKS[task].HEADLINE_METRIC if task in TASKS else None


OBJECTIVE_EVALS = 3  # a run's objective averages this many last evaluations


def run_objective(run_dir: Path, metric: str = "headline") -> float:
    """A run's objective, what a sweep maximises: the mean of ``metric`` over the last
    ``OBJECTIVE_EVALS`` evaluations in ``<run_dir>/eval.csv`` (all of them when there are fewer),
    steadier than the final evaluation alone. ``metric``: ``headline`` (the task's physical
    metric: ``reached_3cm``, ``bounces_per_10s``, ``rotations_per_10s``) or any ``eval.csv``
    column, e.g. ``return_mean``."""
    column = headline_of(run_dir) if metric == "headline" else metric
    table = read_csv(Path(run_dir) / "eval.csv")
    if not table.get("frames"):
        raise ValueError(f"{run_dir}/eval.csv holds no evaluation")
    if column not in table:
        raise ValueError(f"{run_dir}/eval.csv has no column {column!r}; columns: {sorted(table)}")
    values = [v for v in table[column] if np.isfinite(v)][-OBJECTIVE_EVALS:]
    if not values:
        raise ValueError(f"{run_dir}/eval.csv holds no value of {column}")
    return float(sum(values) / len(values))
