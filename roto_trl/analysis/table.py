"""The results table (the numbers of the paper's Figure 5): each experiment's physical metrics and
return, mean and max over its seeds, at the final evaluation and at chosen frame counts, with the
authors' published numbers beside them (``assets/reference/authors_curves.csv``).

A run's numbers come from its ``eval.csv`` (one row per evaluation during training, written by
``roto_trl.trainers.evaluation.evaluate``): at ``final`` its last evaluation, at a frame count F
its evaluations interpolated linearly to F (a run whose last evaluation is before F has no value
there and does not count among that row's seeds). Metric names are the reference's:
``return`` (``return_mean``), ``find_time_<tol>_s`` (``find_time_<tol>``), ``reached_<tol>``,
``bounces_per_10s``, ``rotations_per_10s``.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from roto_trl.analysis.runs import Run, by_experiment, run_csv
from roto_trl.utils.cli import frame_count, frames_label
from roto_trl.utils.resources import resource_path

REFERENCE_FILE = "reference/authors_curves.csv"  # under assets/
FINAL = "final"


def parse_frames(text: str) -> list[int]:
    """``"2M,5M,10M"`` -> ``[2_000_000, 5_000_000, 10_000_000]`` (``utils.cli.frame_count``'s
    forms); a ``ValueError`` naming the bad item otherwise."""
    return [frame_count(item, "--at") for item in text.split(",")]


def table_metric(column: str) -> str | None:
    """The table's (the reference's) name of an ``eval.csv`` column, or None if not in the table."""
    if column == "return_mean":
        return "return"
    if column.startswith("find_time_"):
        return f"{column}_s"
    if column.startswith("reached_") or column.endswith("_per_10s"):
        return column
    return None


def run_values(run: Run, frames: int | None) -> dict[str, float]:
    """``metric -> value`` of one run at its last evaluation (``frames`` None) or interpolated to
    ``frames``; empty when the run's last evaluation is before ``frames``."""
    ev = run_csv(run, "eval.csv", "the table needs runs that have evaluated at least once")
    at = np.asarray(ev["frames"], dtype=float)
    if frames is not None and frames > at[-1]:
        return {}
    values = {}
    for column, series in ev.items():
        metric = table_metric(column)
        y = np.asarray(series, dtype=float)
        known = ~np.isnan(y)  # a column that appeared after the first evaluation
        if metric is None or not known.any():
            continue
        if frames is None:
            if known[-1]:
                values[metric] = float(y[-1])
        elif at[known][0] <= frames:
            values[metric] = float(np.interp(frames, at[known], y[known]))
    return values


@dataclass
class Row:
    """One experiment's one metric at one point (``at``: ``"final"`` or a frame count's label)."""

    exp_name: str
    task: str
    at: str
    frames: int  # ``at``'s frame count; at the final evaluation the runs' mean
    metric: str
    seeds: int
    mean: float
    max: float
    ref_frames: int | None = None
    ref_mean: float | None = None
    ref_max: float | None = None
    ref_seeds: int | None = None


Reference = dict[tuple[str, str], dict[int, tuple[float, float, int]]]


def load_reference(path: Path | None = None) -> Reference:
    """The authors' numbers: ``(experiment, metric) -> {frames: (mean, max, seeds)}``."""
    path = path or resource_path("assets", REFERENCE_FILE)
    with path.open(newline="") as handle:
        lines = [line for line in handle if not line.startswith("#")]
    reference: Reference = {}
    for row in csv.DictReader(lines):
        key = (row["experiment"], row["metric"])
        point = (float(row["mean"]), float(row["max"]), int(row["seeds"]))
        reference.setdefault(key, {})[int(row["frames"])] = point
    return reference


def reference_curve(reference: Reference, exp: str, metric: str) -> tuple | None:
    """The authors' whole curve of ``exp``'s ``metric``: ``(frames, mean, max)`` arrays (their
    seeds' mean and best), or None where they kept none."""
    curve = dict(sorted(reference.get((exp, metric), {}).items()))
    if not curve:
        return None
    frames = np.asarray(list(curve), dtype=float)
    return frames, np.asarray([v[0] for v in curve.values()]), np.asarray([v[1] for v in curve.values()])


def results_table(runs: list[Run], at: list[int], reference: Reference | None = None) -> list[Row]:
    """Rows of every experiment of ``runs`` (grouped by ``exp_name``), metric and point: the final
    evaluation, then each of ``at``. With ``reference``: the authors' numbers of the same
    experiment and metric, at their final evaluation beside ours, and at exactly the same frame
    count beside each of ``at`` (none where they kept no evaluation there)."""
    rows = []
    for exp, members in by_experiment(runs).items():
        for frames in [None, *at]:
            per_run = [run_values(run, frames) for run in members]
            reached = [values for values in per_run if values]
            if not reached:
                continue
            if frames is None:
                point = round(float(np.mean([_last_frames(run) for run in members])))
            else:
                point = frames
            metrics = list(dict.fromkeys(m for values in reached for m in values))
            for metric in metrics:
                seeds = np.asarray([values[metric] for values in reached if metric in values])
                row = Row(
                    exp,
                    members[0].task,
                    FINAL if frames is None else frames_label(frames),
                    point,
                    metric,
                    len(seeds),
                    float(seeds.mean()),
                    float(seeds.max()),
                )
                curve = (reference or {}).get((exp, metric), {})
                ref_frames = (max(curve) if curve else None) if frames is None else frames
                if ref_frames in curve:
                    row.ref_frames = ref_frames
                    row.ref_mean, row.ref_max, row.ref_seeds = curve[ref_frames]
                rows.append(row)
    return rows


def _last_frames(run: Run) -> float:
    return run_csv(run, "eval.csv", "the table needs runs that have evaluated")["frames"][-1]


def write_table_csv(rows: list[Row], path: Path, reference: bool) -> Path:
    """One line per row; the ``ref_*`` columns only with ``reference``."""
    header = ["exp_name", "task", "at", "frames", "metric", "seeds", "mean", "max"]
    if reference:
        header += ["ref_frames", "ref_mean", "ref_max", "ref_seeds"]
    with path.open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(header)
        for row in rows:
            writer.writerow(["" if v is None else v for v in (getattr(row, name) for name in header)])
    return path


def _number(value: float | None) -> str:
    if value is None or math.isnan(value):
        return "–"
    return f"{value:.3g}" if abs(value) < 1000 else f"{value:,.0f}"


def table_markdown(rows: list[Row], reference: bool) -> str:
    """One table per task: a line per experiment and point (``ours``; with ``reference`` an
    ``authors`` line under it), each metric as ``mean / max`` over seeds."""
    out = []
    for task in dict.fromkeys(row.task for row in rows):
        task_rows = [row for row in rows if row.task == task]
        metrics = list(dict.fromkeys(row.metric for row in task_rows))
        points: dict[tuple[str, str], dict[str, Row]] = {}
        for row in task_rows:
            points.setdefault((row.exp_name, row.at), {})[row.metric] = row
        header = ["experiment", "at", "", "frames", "seeds", *(f"{m} (mean / max)" for m in metrics)]
        out += [f"## {task}", "", "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
        for (exp, at), by_metric in points.items():
            first = next(iter(by_metric.values()))
            seeds = max(row.seeds for row in by_metric.values())
            cells = [
                f"{_number(r.mean)} / {_number(r.max)}" if (r := by_metric.get(m)) else "–" for m in metrics
            ]
            ours = f"| {exp} | {at} | ours | {frames_label(first.frames)} | {seeds} | "
            out.append(ours + " | ".join(cells) + " |")
            if reference:
                refs = [by_metric.get(m) for m in metrics]
                known = [r for r in refs if r is not None and r.ref_frames is not None]
                cells = [f"{_number(r.ref_mean)} / {_number(r.ref_max)}" if r in known else "–" for r in refs]
                ref_frames = frames_label(known[0].ref_frames) if known else "–"
                ref_seeds = max((r.ref_seeds for r in known), default="–")
                out.append(f"| | | authors | {ref_frames} | {ref_seeds} | {' | '.join(cells)} |")
        out.append("")
    if reference:
        out.append(
            "authors: elle-miller/roto_paper_results (TensorBoard logs under logs/, 4096 worlds), "
            "at their final evaluation beside ours and at the same frame count beside --at points; "
            "their reward scales differ from ours in places: compare physical metrics, not returns."
        )
    return "\n".join(out) + "\n"
