"""What a run did, window by window: its training episodes (the sampled policy that PPO trains)
beside its evaluations (the deterministic controller read out of it).

For each window of ``every`` frames, a metric's training value is the mean over the episodes
that ended in the window (``train.csv``'s ``episode/<metric>``, an iteration's mean, weighted by
its ``episodes``) and its evaluation value the mean of the window's evaluations (``eval.csv``).
The two part where a policy learns something its controller does not show yet, or the other way
round (Baoding's sampled policies turn the balls millions of frames before the deterministic
ones: docs/results_cpu.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from roto_trl.analysis.runs import Run, run_csv
from roto_trl.analysis.stability import training_at
from roto_trl.utils.cli import frames_label


@dataclass
class Window:
    """``(start, end]`` in frames, how many training episodes ended and evaluations ran in it,
    and each metric's training and evaluation mean (NaN where there were none)."""

    start: int
    end: int
    episodes: int
    evaluations: int
    training: dict[str, float]
    evaluation: dict[str, float]


def shared_metrics(train: dict[str, list[float]], evals: dict[str, list[float]]) -> list[str]:
    """The ``eval.csv`` columns that ``train.csv`` logs for the training episodes too
    (``episode/<column>``), with the return first."""
    shared = [k for k in evals if f"episode/{k}" in train]
    return ["return_mean", *shared] if "episode_return" in train else shared


def _training_column(metric: str) -> str:
    return "episode_return" if metric == "return_mean" else f"episode/{metric}"


def run_windows(run: Run, every: int, metrics: list[str] | None = None) -> tuple[list[str], list[Window]]:
    """The run's windows of ``every`` frames up to its last logged iteration, and the metrics
    they hold (``metrics``, default :func:`shared_metrics`); a ``ValueError`` names a metric
    that one of the two files lacks."""
    train = run_csv(run, "train.csv", "the training episodes are read from it")
    evals = run_csv(run, "eval.csv", "the evaluations are read from it")
    metrics = metrics or shared_metrics(train, evals)
    for metric in metrics:
        if metric not in evals or _training_column(metric) not in train:
            raise ValueError(
                f"{run.path}: {metric} is not logged for both the training episodes and the "
                f"evaluations; choose from {', '.join(shared_metrics(train, evals))}"
            )
    frames = np.asarray(train["frames"], dtype=float)
    episodes = np.nan_to_num(np.asarray(train.get("episodes", []), dtype=float))
    eval_frames = np.asarray(evals["frames"], dtype=float)
    ones = np.ones_like(eval_frames)
    last = int(frames[-1]) if frames.size else 0
    # a run stops at the first iteration past its budget: a sliver of under half a window at the
    # end joins the window before it rather than standing as a window of a few episodes
    starts = list(range(0, last, every))
    if len(starts) > 1 and last - starts[-1] < every / 2:
        starts.pop()
    windows = []
    for start, end in zip(starts, [*starts[1:], last], strict=True):
        inside = (frames > start) & (frames <= end)
        evaluated = int(((eval_frames > start) & (eval_frames <= end)).sum())
        training, evaluation = {}, {}
        for metric in metrics:
            values = np.asarray(train[_training_column(metric)], dtype=float)
            training[metric] = training_at(frames, values, episodes, [end], window=end - start)[0]
            scores = np.asarray(evals[metric], dtype=float)
            evaluation[metric] = training_at(eval_frames, scores, ones, [end], end - start, until=last)[0]
        windows.append(Window(start, end, int(episodes[inside].sum()), evaluated, training, evaluation))
    return metrics, windows


def _number(value: float) -> str:
    return "–" if math.isnan(value) else f"{value:.3g}"


def windows_markdown(label: str, metrics: list[str], windows: list[Window]) -> str:
    """One run's windows as a Markdown table: the training episodes' columns, then the
    evaluations'."""
    header = ["frames", "training episodes", *metrics, "evaluations", *(f"eval {m}" for m in metrics)]
    lines = [f"### {label}", "", "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for w in windows:
        cells = [
            f"{frames_label(w.start) if w.start else '0'}-{frames_label(round(w.end, -4) or w.end)}",
            str(w.episodes),
            *(_number(w.training[m]) for m in metrics),
            str(w.evaluations),
            *(_number(w.evaluation[m]) for m in metrics),
        ]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def windows_csv_rows(label: str, metrics: list[str], windows: list[Window]) -> tuple[list[str], list[list]]:
    """The same numbers as CSV: a header and one row per window."""
    header = ["run", "start", "end", "episodes", *(f"train_{m}" for m in metrics), "evaluations"]
    header += [f"eval_{m}" for m in metrics]
    rows = [
        [label, w.start, w.end, w.episodes, *(w.training[m] for m in metrics), w.evaluations]
        + [w.evaluation[m] for m in metrics]
        for w in windows
    ]
    return header, rows
