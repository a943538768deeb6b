"""Finding run directories, checking what each can be counted for, and aggregating their logs
across seeds.

Every analysis tool reads runs through :func:`find_runs` and :func:`countable`: runs are grouped
by what they trained (``Run.group``: the experiment, and where runs of one experiment differ, their
frame budget and the settings they differ in), a run that failed, ended early or holds no
evaluation is left out with a line saying so, a seed that two runs of one group share is refused,
and a group whose runs come from different commits is flagged.
"""

from __future__ import annotations

import glob
import json
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from omegaconf import OmegaConf

from roto_trl.trainers.loggers import cut_last_line, read_csv
from roto_trl.trainers.provenance import read_provenance
from roto_trl.utils.cli import frames_label

# settings that say nothing about what a run trained: where it ran, how it logged, its seed
NOT_SETTINGS = ("seed", "run_dir", "resume", "torch_threads", "progress", "logger", "checkpoint", "device")
NOT_SETTINGS_ENV = ("num_threads",)


@dataclass
class Run:
    """A run directory of ``train.py`` and what it was."""

    path: Path
    exp_name: str
    task: str
    seed: int
    config: dict
    frames: int = 0  # frames trained (the last row of train.csv)
    finished: bool = False  # summary.json written: the run reached its budget or time limit
    problems: list[str] = field(default_factory=list)  # why it cannot be counted (countable)
    notes: list[str] = field(default_factory=list)  # what was read around (a cut last line)
    group: str = ""  # what it trained (find_runs)

    @property
    def label(self) -> str:
        return f"{self.exp_name}/{self.path.name}"

    @property
    def budget(self) -> int:
        return int(self.config["total_frames"])

    @property
    def commits(self) -> set[str]:
        """The commits its sittings ran (``provenance.json``), none for runs made before it."""
        return {str(s["commit"]) + ("+changes" if s["dirty"] else "") for s in read_provenance(self.path)}


def settings(config: dict) -> dict:
    """The settings of a run's config that say what it trained, flattened (``agent.lr``: 3e-4)."""

    def flat(node, prefix=""):
        out = {}
        for key, value in node.items():
            if isinstance(value, dict) and key != "overrides":
                out |= flat(value, f"{prefix}{key}.")
            else:
                out[f"{prefix}{key}"] = value
        return out

    kept = {k: v for k, v in config.items() if k not in NOT_SETTINGS}
    if isinstance(kept.get("env", {}).get("overrides"), dict):
        env = dict(kept["env"])
        env["overrides"] = {k: v for k, v in env["overrides"].items() if k not in NOT_SETTINGS_ENV}
        kept["env"] = env
    return flat(kept)


def name_groups(runs: list[Run]) -> None:
    """Set each run's ``group``: its ``exp_name``, and where runs of one ``exp_name`` differ in
    their settings, the budget and the other settings that tell them apart."""
    for exp in dict.fromkeys(r.exp_name for r in runs):
        members = [r for r in runs if r.exp_name == exp]
        flats = [settings(r.config) for r in members]
        keys = sorted({k for f in flats for k in f})
        differ = [k for k in keys if len({repr(f.get(k)) for f in flats}) > 1 and k != "total_frames"]
        budgets = len({r.budget for r in members}) > 1
        for run, flat in zip(members, flats, strict=True):
            parts = [f"{frames_label(run.budget)} frames"] if budgets else []
            parts += [f"{k}={flat.get(k)}" for k in differ]
            run.group = f"{exp} [{', '.join(parts)}]" if parts else exp


def check_run(run: Run) -> None:
    """Fill ``run.frames``, ``finished``, ``problems`` and ``notes`` from its directory."""
    train = run.path / "train.csv"
    frames = read_csv(train).get("frames", []) if train.is_file() else []  # a column, not a setting
    run.frames = int(frames[-1]) if frames else 0
    run.finished = (run.path / "summary.json").is_file()
    evaluations = read_csv(run.path / "eval.csv") if (run.path / "eval.csv").is_file() else {}
    for name in ("train.csv", "eval.csv"):
        if cut_last_line(run.path / name):
            run.notes.append(f"its last line of {name} is cut (a kill while writing it) and is left out")
    if (run.path / "error.txt").is_file():
        first = ((run.path / "error.txt").read_text().strip().splitlines() or [""])[-1]
        run.problems.append(f"it failed ({first[:120]})")
    elif not evaluations:
        run.problems.append("it holds no evaluation")
    elif not run.finished:
        run.problems.append(
            f"it ended early, at {run.frames:,} of {run.budget:,} frames (or is still running)"
        )


def find_runs(patterns: list[str]) -> list[Run]:
    """Run directories matching ``patterns`` (paths or globs), in sorted order.

    Raises ``ValueError`` naming the patterns when nothing matches, or a match is not a run.
    """
    paths: list[Path] = []
    for pattern in patterns:
        # a glob matches run directories only: not a sweep's directory, not analyse.py's output
        globbed = [Path(p) for p in glob.glob(pattern) if (Path(p) / "config.yaml").is_file()]
        matched = sorted(globbed) or ([Path(pattern)] if Path(pattern).exists() else [])
        if not matched:
            raise ValueError(f"no run directories match {pattern!r}; give run directories or a quoted glob")
        paths += [p for p in matched if p not in paths]
    runs = []
    for path in paths:
        if not (path / "config.yaml").is_file():
            raise ValueError(f"{path} is not a run directory of train.py (no config.yaml)")
        try:
            cfg = OmegaConf.to_container(OmegaConf.load(path / "config.yaml"))
        except Exception as err:  # yaml's errors have several types
            raise ValueError(
                f"{path}/config.yaml cannot be read ({type(err).__name__}); restore it"
            ) from None
        run = Run(path, cfg["exp_name"], cfg["env"]["task"], int(cfg["seed"]), cfg)
        check_run(run)
        runs.append(run)
    name_groups(runs)
    return runs


def countable(runs: list[Run], command: str, *, unfinished: bool = False) -> list[Run]:
    """The runs a table or figure can count, after saying in one line each which are left out and
    why (failed, ended early, no evaluation; ``unfinished`` keeps runs still going), what was read
    around, and which groups mix commits. A seed that two runs of one group share is a
    ``ValueError`` naming both, as is having nothing left."""
    kept = []
    for run in runs:
        for note in run.notes:
            print(f"analyse {command}: note: {run.path}: {note}", file=sys.stderr)
        problems = [p for p in run.problems if not (unfinished and p.startswith("it ended early"))]
        if problems:
            print(f"analyse {command}: left out {run.path}: {'; '.join(problems)}", file=sys.stderr)
            continue
        kept.append(run)
    seen: dict[tuple[str, int], Run] = {}
    for run in kept:
        other = seen.setdefault((run.group, run.seed), run)
        if other is not run:
            raise ValueError(
                f"{other.path} and {run.path} are both seed {run.seed} of {run.group}: keep one of them"
            )
    for group, members in by_experiment(kept).items():
        commits = set().union(*(r.commits for r in members))
        if len(commits) > 1:
            print(
                f"analyse {command}: warning: {group} mixes runs of commits {sorted(commits)}",
                file=sys.stderr,
            )
    if not kept:
        raise ValueError("no run left to count (see the lines above)")
    return kept


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
    """Runs grouped by what they trained (``Run.group``), groups in first-seen order."""
    groups: dict[str, list[Run]] = {}
    for run in runs:
        groups.setdefault(run.group or run.exp_name, []).append(run)
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
