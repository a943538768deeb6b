"""How well each run holds what it learns, and how large its PPO steps were: one row per run.

A run's evaluations during training (``eval.csv``) give its best and final value of the task's
headline metric; a run holds what it learns when its final evaluation is at least
``HOLD_FRACTION`` of its best. The step sizes are the medians over the run's iterations of the
per-iteration median per-minibatch KL (``kl_k3_median``, skrl's estimator) and clip fraction
(``clip_fraction_median``) from ``train.csv``. ``eval.json`` (``evaluate.py``, 100 episodes of the
best checkpoint for the results table) adds its headline value and episode count.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass

import numpy as np

from roto_trl.analysis.runs import Run, run_csv

HEADLINE = {"bounce": "bounces_per_10s", "find": "reached_3cm", "baoding": "rotations_per_10s"}
HOLD_FRACTION = 0.8


@dataclass
class RunStability:
    """One run's best and final evaluation of ``metric``, its step sizes and speed."""

    label: str
    seed: int
    metric: str
    frames: int  # at the final evaluation
    best: float
    best_frames: int
    final: float
    kl_median: float
    clip_median: float
    frames_per_s: float
    checkpoint_value: float | None = None  # eval.json's value of ``metric`` (best checkpoint)
    checkpoint_episodes: int | None = None

    @property
    def held(self) -> float:
        """final / best (1 when nothing was learnt: best 0)."""
        return self.final / self.best if self.best > 0 else 1.0


def run_stability(run: Run) -> RunStability:
    """The run's row; a ``ValueError`` naming the missing log otherwise."""
    metric = HEADLINE[run.task]
    ev = run_csv(run, "eval.csv", "stability needs runs that have evaluated at least once")
    train = run_csv(run, "train.csv", "stability needs the training log")
    if metric not in ev:
        raise ValueError(f"{run.path}/eval.csv has no {metric} column; it is not a {run.task} run's log")
    values = np.asarray(ev[metric], dtype=float)
    best = int(np.nanargmax(values))
    row = RunStability(
        label=run.label,
        seed=run.seed,
        metric=metric,
        frames=int(ev["frames"][-1]),
        best=float(values[best]),
        best_frames=int(ev["frames"][best]),
        final=float(values[-1]),
        kl_median=_median(train.get("kl_k3_median")),
        clip_median=_median(train.get("clip_fraction_median")),
        frames_per_s=_median(train.get("fps")),
    )
    checkpoint = run.path / "eval.json"
    if checkpoint.is_file():
        result = json.loads(checkpoint.read_text())
        row.checkpoint_value = result["physical"].get(metric)
        row.checkpoint_episodes = int(result["episodes"])
    return row


def _median(series: list[float] | None) -> float:
    values = np.asarray(series if series is not None else [], dtype=float)
    values = values[~np.isnan(values)]
    return float(np.median(values)) if values.size else math.nan


def stability_markdown(rows: list[RunStability]) -> str:
    """A Markdown table, one line per run."""
    header = (
        "| run | seed | metric | frames | best (at) | final | final / best | best checkpoint (episodes)"
        " | median KL | median clip | frames/s |"
    )
    lines = [header, "|" + "---|" * 11]
    for r in rows:
        checkpoint = "–"
        if r.checkpoint_value is not None:
            checkpoint = f"{r.checkpoint_value:.3g} ({r.checkpoint_episodes})"
        flag = "" if r.held >= HOLD_FRACTION else " (fell back)"
        lines.append(
            f"| {r.label} | {r.seed} | {r.metric} | {r.frames:,} | {r.best:.3g} ({r.best_frames:,}) | "
            f"{r.final:.3g} | {r.held:.2f}{flag} | {checkpoint} | {r.kl_median:.3g} | "
            f"{r.clip_median:.2f} | {r.frames_per_s:,.0f} |"
        )
    return "\n".join(lines) + "\n"
