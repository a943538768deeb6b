"""Two sets of runs that differ in one choice, paired by seed: the table a default is decided on.

A change to the recipe (the precision, Adam's eps, the weight decay) is judged on the same seeds run
both ways (docs/recipe.md): a seed's pair shares its worlds and its first weights, so
the difference of the pair carries much less of the seed-to-seed spread than two means do.

Each pair compares the final policies and whether each run held what it learnt:
- when every run has its final checkpoint re-evaluated like its best one (``eval-latest.json``
  made as ``eval.json``, e.g. ``evaluate.py run=<run> episodes=1000`` and ``evaluate.py
  run=<run> checkpoint=latest episodes=1000``), the final
  checkpoint's value and final / best checkpoint (``RunStability.held_checkpoints``);
- otherwise the final evaluation during training (``eval.csv``) and final / best evaluation;
  which of the two was used is printed with the table.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from roto_trl.analysis.runs import Run
from roto_trl.analysis.stability import HOLD_FRACTION, RunStability, held_cell, run_stability

IGNORED_KEYS = ("run_dir", "seed")  # differ between any two runs; not the choice compared


def paired_difference(test: list[float], base: list[float]) -> tuple[float, float]:
    """The mean of ``test - base`` over pairs ``[P]`` and its standard error, the differences'
    sample standard deviation (ddof 1) / sqrt(P); NaN for a single pair."""
    differences = np.asarray(test, dtype=float) - np.asarray(base, dtype=float)
    if differences.size < 2:
        return float(differences.mean()), math.nan
    return float(differences.mean()), float(differences.std(ddof=1) / math.sqrt(differences.size))


def flat_config(config: dict, prefix: str = "") -> dict[str, object]:
    """``{"agent": {"lr": 1e-3}}`` -> ``{"agent.lr": 1e-3}`` (lists stay values)."""
    flat: dict[str, object] = {}
    for key, value in config.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            flat.update(flat_config(value, f"{name}."))
        else:
            flat[name] = value
    return flat


def config_differences(base: list[dict], test: list[dict]) -> dict[str, tuple[object, object]]:
    """``key -> (base value, test value)`` for the config keys that are alike within each set
    and differ between them (``run_dir`` and ``seed`` left out): what the comparison is of."""
    differences = {}
    base_flat, test_flat = [flat_config(c) for c in base], [flat_config(c) for c in test]
    for key in sorted(set().union(*base_flat, *test_flat) - set(IGNORED_KEYS)):
        base_values = {repr(c.get(key)) for c in base_flat}
        test_values = {repr(c.get(key)) for c in test_flat}
        if len(base_values) == len(test_values) == 1 and base_values != test_values:
            differences[key] = (base_flat[0].get(key), test_flat[0].get(key))
    return differences


@dataclass
class Comparison:
    """Paired rows (one per seed in both sets, ascending) and where their values come from."""

    metric: str
    source: str  # "final checkpoints, N episodes" or "final evaluations during training"
    seeds: list[int]
    base: list[RunStability]  # [P], in ``seeds`` order
    test: list[RunStability]  # [P]
    left_out: list[int]  # seeds in only one set
    differences: dict[str, tuple[object, object]]
    checkpoints: bool  # the values are the checkpoints' re-evaluations

    def final(self, row: RunStability) -> float:
        return row.final_checkpoint_value if self.checkpoints else row.final

    def best(self, row: RunStability) -> float:
        return row.checkpoint_value if self.checkpoints else row.best

    def held(self, row: RunStability) -> float:
        return row.held_checkpoints if self.checkpoints else row.held


def by_seed(runs: list[Run], option: str, metric: str | None) -> dict[int, tuple[Run, RunStability]]:
    """``seed -> (run, its stability row)``; a ``ValueError`` when a set holds two runs of one seed."""
    out: dict[int, tuple[Run, RunStability]] = {}
    for run in runs:
        if run.seed in out:
            raise ValueError(f"{option} holds two runs of seed {run.seed}: give one run per seed")
        out[run.seed] = (run, run_stability(run, metric=metric))
    return out


def compare_runs(base_runs: list[Run], test_runs: list[Run], metric: str | None = None) -> Comparison:
    """Pair two sets of runs of one task by seed (see the module's docstring) on ``metric``
    (default the task's headline metric; see ``run_stability``)."""
    base_set, test_set = by_seed(base_runs, "--against", metric), by_seed(test_runs, "the runs", metric)
    seeds = sorted(base_set.keys() & test_set.keys())
    if not seeds:
        raise ValueError(
            f"no seed is in both sets (runs: {sorted(test_set)}, --against: {sorted(base_set)}):"
            " run the same seeds both ways"
        )
    base, test = [base_set[s][1] for s in seeds], [test_set[s][1] for s in seeds]
    paired = base + test
    checkpoints = all(r.final_checkpoint_value is not None for r in paired)
    if checkpoints:
        episodes = sorted({r.final_checkpoint_episodes for r in paired})
        counts = str(episodes[0]) if len(episodes) == 1 else f"{episodes[0]}-{episodes[-1]}"
        source = f"final checkpoints re-evaluated on {counts} episodes"
    else:
        source = "final evaluations during training (not every run has eval-latest.json made like eval.json)"
    return Comparison(
        metric=paired[0].metric,
        source=source,
        seeds=seeds,
        base=base,
        test=test,
        left_out=sorted(base_set.keys() ^ test_set.keys()),
        differences=config_differences(
            [base_set[s][0].config for s in seeds], [test_set[s][0].config for s in seeds]
        ),
        checkpoints=checkpoints,
    )


def comparison_markdown(c: Comparison) -> str:
    """What differs, one line per seed (base, test, test - base, holding, frames/s) and the
    summary: means, the paired difference +- its standard error, runs holding."""
    what = "; ".join(f"{key}: {b!r} -> {t!r}" for key, (b, t) in c.differences.items())
    lines = [
        f"base (--against) -> test: {what or 'no config key differs'}",
        f"{c.metric}, {c.source}; holds: final / best >= {HOLD_FRACTION}",
        "",
        "| seed | base final | test final | test - base | base final / best | test final / best"
        " | base frames/s | test frames/s |",
        "|" + "---|" * 8,
    ]
    for seed, b, t in zip(c.seeds, c.base, c.test, strict=True):
        lines.append(
            f"| {seed} | {c.final(b):.3g} | {c.final(t):.3g} | {c.final(t) - c.final(b):+.3g} | "
            f"{held_cell(c.held(b))} | {held_cell(c.held(t))} | "
            f"{b.frames_per_s:,.0f} | {t.frames_per_s:,.0f} |"
        )
    s = summary(c)
    spread = (
        f" +- {s['standard_error']:.2g} ({s['difference_in_se']:+.2f} standard errors)"
        if len(c.seeds) > 1
        else " (one pair: no standard error)"
    )
    lines += [
        "",
        f"{len(c.seeds)} seed{'s' if len(c.seeds) > 1 else ''}: final {s['base_final']:.3g} -> "
        f"{s['test_final']:.3g}, paired difference {s['difference']:+.3g}{spread}; "
        f"best {s['base_best']:.3g} -> {s['test_best']:.3g}; holding {s['base_holding']} -> "
        f"{s['test_holding']} of {len(c.seeds)}; frames/s x{s['frames_per_s_ratio']:.2f}",
    ]
    if c.left_out:
        lines.append(f"left out (in one set only): seeds {', '.join(map(str, c.left_out))}")
    return "\n".join(lines) + "\n"


def summary(c: Comparison) -> dict[str, float]:
    """The means over pairs, the paired difference of the finals and its standard error, the runs
    holding in each set and the ratio of the median frames/s (test / base)."""
    difference, standard_error = paired_difference([c.final(r) for r in c.test], [c.final(r) for r in c.base])
    base_fps, test_fps = (float(np.median([r.frames_per_s for r in rows])) for rows in (c.base, c.test))
    return {
        "base_final": float(np.mean([c.final(r) for r in c.base])),
        "test_final": float(np.mean([c.final(r) for r in c.test])),
        "difference": difference,
        "standard_error": standard_error,
        "difference_in_se": difference / standard_error if standard_error > 0 else math.nan,
        "base_best": float(np.mean([c.best(r) for r in c.base])),
        "test_best": float(np.mean([c.best(r) for r in c.test])),
        "base_holding": sum(c.held(r) >= HOLD_FRACTION for r in c.base),
        "test_holding": sum(c.held(r) >= HOLD_FRACTION for r in c.test),
        "frames_per_s_ratio": test_fps / base_fps if base_fps > 0 else math.nan,
    }


def comparison_csv_rows(c: Comparison) -> tuple[list[str], list[list]]:
    """Header and one row per seed for ``compare.csv``."""
    header = ["seed", "base_final", "test_final", "difference", "base_best", "test_best"]
    header += ["base_held", "test_held", "base_frames_per_s", "test_frames_per_s"]
    rows = []
    for seed, b, t in zip(c.seeds, c.base, c.test, strict=True):
        rows.append([seed, c.final(b), c.final(t), c.final(t) - c.final(b), c.best(b), c.best(t)])
        rows[-1] += [c.held(b), c.held(t), b.frames_per_s, t.frames_per_s]
    return header, rows
