"""How well each run holds what it learns, and how large its PPO steps were: one row per run.

A run's evaluations during training (``eval.csv``) give its best and final value of the task's
headline metric; a run holds what it learns when its final evaluation is at least
``HOLD_FRACTION`` of its best. The step sizes are the medians over the run's iterations of the
per-iteration median per-minibatch KL (``kl_k3_median``, skrl's estimator) and clip fraction
(``clip_fraction_median``) from ``train.csv``. ``eval.json`` (``evaluate.py``, 100 episodes of the
best checkpoint for the results table) adds its headline value and episode count.

The best of a run's evaluations is the maximum of some twenty noisy draws, so final / best reads
low even for a run that kept what it learnt (Find's 0-or-1 metric on 128 worlds: a flat run
passes 0.8 most of the time, but not always: docs/recipe.md). ``eval-latest.json`` (``evaluate.py
checkpoint=latest``; ``eval_latest.json`` in runs evaluated before that name) gives the fair test:
the final checkpoint against the best one,
both re-evaluated on the same fresh episodes (``evaluate.py`` seeds them alike) with the same
policy form, ``held_checkpoints``.

The training episodes (the stochastic policy) give a second view at chosen frame marks: the mean
of the evaluation's headline metric (``episode/<headline>`` in ``train.csv``; in runs logged
before training wrote it, the task's episode metric ``TRAINING_METRIC``) over the episodes that
ended in the ``TRAINING_WINDOW`` frames before each mark, weighted by how many ended in each
iteration; and the same mean before the best and before the final evaluation, which tells a
policy that fell back (both views drop) from a deterministic controller that fell back while the
policy PPO trains held (the training episodes do not drop).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from roto_trl.analysis.runs import Run, read_json, run_csv
from roto_trl.analysis.table import frames_label
from roto_trl.envs.factory import TASKS
from roto_trl.trainers.evaluation import selection_key

HOLD_FRACTION = 0.8
TRAINING_METRIC = {  # runs whose train.csv lacks episode/<headline>
    "bounce": "episode/bounces",
    "find": "episode/find_time_3cm",
    "baoding": "episode/rotations",
}
TRAINING_WINDOW = 49_152  # 12 iterations of 256 worlds x 16 steps: a few hundred episodes
MARK_FRACTIONS = (0.15, 0.25, 0.5, 0.75, 1.0)  # of the budget: 0.3M, 0.5M, 1M, 1.5M, 2M at 2M frames
DEFAULT_MARKS = tuple(round(f * 2_000_000) for f in MARK_FRACTIONS)


def default_marks(runs: list[Run]) -> list[int]:
    """The training-episode marks of a table of ``runs``: ``MARK_FRACTIONS`` of their largest
    budget."""
    budget = max(run.budget for run in runs)
    return [round(f * budget) for f in MARK_FRACTIONS]


# the final checkpoint's result (evaluate.py checkpoint=latest), and its name in runs evaluated before
LATEST_RESULTS = ("eval-latest.json", "eval_latest.json")


def training_at(
    frames: np.ndarray,
    values: np.ndarray,
    episodes: np.ndarray,
    marks,
    window: int = TRAINING_WINDOW,
    until: int | None = None,
) -> list[float]:
    """The episode-weighted mean of ``values`` over the entries logged at ``frames`` in
    ``(mark - window, mark]``, for each mark; NaN where the log ends before the mark or no
    episode ended in the window.

    All arrays are ``[entries]``: an iteration's mean over the ``episodes[i]`` episodes that
    ended in it (NaN when none did), or one episode with weight 1. ``until``: the frames the log
    covers (default its last entry; give it for a per-episode log, whose last episode ends
    before the budget).
    """
    until = (frames[-1] if frames.size else 0) if until is None else until
    out = []
    for mark in marks:
        inside = (frames > mark - window) & (frames <= mark) & (episodes > 0) & ~np.isnan(values)
        if until < mark or not inside.any():
            out.append(math.nan)
            continue
        out.append(float(np.average(values[inside], weights=episodes[inside])))
    return out


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
    final_checkpoint_value: float | None = None  # eval-latest.json's value (the final checkpoint)
    final_checkpoint_episodes: int | None = None
    training_metric: str = ""
    training: dict[int, float] | None = None  # mark (frames) -> training episodes' mean
    training_at_best: float = math.nan  # training episodes' mean before the best evaluation
    training_at_final: float = math.nan  # ... before the final evaluation

    @property
    def held(self) -> float:
        """final / best (1 when nothing was learnt: best 0)."""
        return self.final / self.best if self.best > 0 else 1.0

    @property
    def held_checkpoints(self) -> float:
        """The final checkpoint's re-evaluation / the best one's (NaN unless both were made alike)."""
        if self.checkpoint_value is None or self.final_checkpoint_value is None:
            return math.nan
        return self.final_checkpoint_value / self.checkpoint_value if self.checkpoint_value > 0 else 1.0


def best_evaluation(values: np.ndarray, returns, metric: str) -> int:
    """The index of the evaluation a run's ``best.pt`` holds: ranked as training ranks them
    (``selection_key``: the headline metric, then the return; the earliest of exact ties).

    ``values`` ``[E]`` the headline metric (NaN ranks last), ``returns`` ``[E]`` the mean returns
    or None (logs without them rank by the metric alone).
    """
    returns = np.zeros(len(values)) if returns is None else np.asarray(returns, dtype=float)
    results = [
        {metric: -math.inf if math.isnan(v) else v, "return_mean": -math.inf if math.isnan(r) else r}
        for v, r in zip(values.tolist(), returns.tolist(), strict=True)
    ]
    return max(range(len(results)), key=lambda i: selection_key(results[i], metric))


def run_stability(run: Run, marks=DEFAULT_MARKS, metric: str | None = None) -> RunStability:
    """The run's row, with the training episodes at ``marks``; a ``ValueError`` naming the
    missing log otherwise.

    ``metric``: an ``eval.csv`` column to report (default the task's headline metric; e.g.
    ``return_mean`` on Baoding, whose rotations stay 0 for millions of frames). The best
    evaluation is always the one ``best.pt`` holds, ranked by the headline metric as training
    ranks them; the row gives ``metric`` there.
    """
    headline = TASKS[run.task].HEADLINE_METRIC
    metric = metric or headline
    ev = run_csv(run, "eval.csv", "stability needs runs that have evaluated at least once")
    train = run_csv(run, "train.csv", "stability needs the training log")
    if headline not in ev:
        raise ValueError(f"{run.path}/eval.csv has no {headline} column; it is not a {run.task} run's log")
    if metric not in ev:
        known = ", ".join(k for k in ev if k not in ("frames", "iteration", "time"))
        raise ValueError(f"--metric {metric}: {run.path}/eval.csv has no such column; give one of {known}")
    values = np.asarray(ev[metric], dtype=float)
    best = best_evaluation(np.asarray(ev[headline], dtype=float), ev.get("return_mean"), headline)
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
        training_metric=training_column(metric, train, run.task),
    )
    if row.training_metric in train and "episodes" in train:
        frames, values, episodes = (
            np.asarray(train[k], dtype=float) for k in ("frames", row.training_metric, "episodes")
        )
        row.training = dict(zip(marks, training_at(frames, values, episodes, marks), strict=True))
        row.training_at_best, row.training_at_final = training_at(
            frames, values, episodes, [row.best_frames, row.frames]
        )
    best_eval = read_json(run.path / "eval.json")
    final_eval = next(filter(None, (read_json(run.path / name) for name in LATEST_RESULTS)), None)
    if best_eval is not None:
        row.checkpoint_value = result_value(best_eval, metric)
        row.checkpoint_episodes = int(best_eval["episodes"])
        # only an evaluation made like the best checkpoint's compares with it
        if final_eval is not None and all(
            final_eval.get(k) == best_eval.get(k) for k in ("episodes", "seed", "policy")
        ):
            row.final_checkpoint_value = result_value(final_eval, metric)
            row.final_checkpoint_episodes = int(final_eval["episodes"])
    return row


def training_column(metric: str, train: dict, task: str) -> str:
    """The ``train.csv`` column of the training episodes' ``metric``: ``episode/<metric>``, the
    return's ``episode_return``, or in logs from before ``episode/<headline>`` the task's
    ``TRAINING_METRIC``."""
    if metric == "return_mean":
        return "episode_return"
    return f"episode/{metric}" if f"episode/{metric}" in train else TRAINING_METRIC[task]


def result_value(result: dict, metric: str) -> float | None:
    """``metric`` in an ``evaluate.py`` result: the return at its top level, physical metrics
    under ``physical``."""
    return result.get(metric) if metric == "return_mean" else result["physical"].get(metric)


def _median(series: list[float] | None) -> float:
    values = np.asarray(series if series is not None else [], dtype=float)
    values = values[~np.isnan(values)]
    return float(np.median(values)) if values.size else math.nan


def stability_markdown(rows: list[RunStability], marks: list[int]) -> str:
    """A Markdown table, one line per run; the training column lists the values at ``marks``."""
    at = " / ".join(frames_label(m) for m in marks)
    header = (
        f"| run | seed | training episodes at {at} | metric | frames | best (at) | final | final / best"
        " | training episodes before best / final eval | best checkpoint (episodes)"
        " | final checkpoint, / best checkpoint | median KL | median clip | frames/s |"
    )
    lines = [header, "|" + "---|" * 14]
    for r in rows:
        checkpoint = final_checkpoint = "–"
        if r.checkpoint_value is not None:
            checkpoint = f"{r.checkpoint_value:.3g} ({r.checkpoint_episodes})"
        if r.final_checkpoint_value is not None:
            final_checkpoint = f"{r.final_checkpoint_value:.3g}, {held_cell(r.held_checkpoints)}"
        training = " / ".join(_cell((r.training or {}).get(m, math.nan)) for m in marks)
        lines.append(
            f"| {r.label} | {r.seed} | {r.training_metric}: {training} | {r.metric} | {r.frames:,} | "
            f"{r.best:.3g} ({r.best_frames:,}) | "
            f"{r.final:.3g} | {held_cell(r.held)} | "
            f"{_cell(r.training_at_best)} / {_cell(r.training_at_final)} | "
            f"{checkpoint} | {final_checkpoint} | "
            f"{r.kl_median:.3g} | {r.clip_median:.2f} | {r.frames_per_s:,.0f} |"
        )
    return "\n".join(lines) + "\n"


def held_cell(ratio: float) -> str:
    """final / best as a table cell, flagged when the run fell back (under ``HOLD_FRACTION``)."""
    return f"{ratio:.2f}" + ("" if ratio >= HOLD_FRACTION else " (fell back)")


def _cell(value: float) -> str:
    return "–" if math.isnan(value) else f"{value:.2f}"


def stability_csv_rows(rows: list[RunStability], marks: list[int]) -> tuple[list[str], list[list]]:
    """Header and rows for ``stability.csv``: one column per field, ``training_<mark>`` per mark."""
    fields = [k for k in vars(rows[0]) if k != "training"]
    header = [*fields, *(f"training_{frames_label(m)}" for m in marks), "held", "held_checkpoints"]
    body = [
        [
            *(getattr(r, k) for k in fields),
            *((r.training or {}).get(m, math.nan) for m in marks),
            r.held,
            r.held_checkpoints,
        ]
        for r in rows
    ]
    return header, body
