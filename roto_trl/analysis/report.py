"""A run's report: ``index.md`` in the run directory, one file that shows how the run went.

It embeds the plots (``plots/eval.png``, ``plots/train.png``) and tabulates ``summary.json``
(frames, wall time, best and final evaluation) and ``eval.json`` (the physical metrics of the
best checkpoint, written by ``roto_trl/evaluate.py``). Missing pieces (a run still going, a run
never evaluated) are said so, not skipped silently.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from roto_trl.analysis.metrics import describe
from roto_trl.analysis.runs import read_json


def _shown(value: Any) -> str:
    return (
        f"{value:,.4g}"
        if isinstance(value, float)
        else f"{value:,}"
        if isinstance(value, int)
        else str(value)
    )


def _table(rows: dict[str, Any]) -> list[str]:
    lines = ["| | |", "|---|---|"]
    lines += [f"| {key} | {_shown(value)} |" for key, value in rows.items()]
    return lines


def _metric_table(rows: dict[str, Any]) -> list[str]:
    """Logged numbers by key, with what each is and its unit (``analysis.metrics``)."""
    lines = ["| metric | what | unit | value |", "|---|---|---|---|"]
    for key, value in rows.items():
        name, unit = describe(key)
        lines.append(f"| `{key}` | {name} | {unit} | {_shown(value)} |")
    return lines


def write_index(run_dir: Path) -> Path:
    """Write ``<run_dir>/index.md`` from what the run directory holds; returns its path."""
    run_dir = Path(run_dir)
    summary = read_json(run_dir / "summary.json")
    evaluation = read_json(run_dir / "eval.json")
    title = summary["exp_name"] if summary else run_dir.name
    lines = [f"# {title}: {run_dir.name}", ""]
    if summary:
        lines += _table(
            {
                "task": summary["task"],
                "seed": summary["seed"],
                "frames": summary["frames"],
                "iterations": summary["iterations"],
                "wall time (min)": summary["wall_time_s"] / 60.0,
                "frames / s (evaluation included)": summary["frames_per_s"] or 0.0,
                "evaluation's share of the wall time": summary["eval_share"],
            }
        )
    else:
        lines.append("No `summary.json` yet: the run has not finished.")
    lines += ["", "## Evaluation", "", "![evaluation](plots/eval.png)", ""]
    if summary:
        for label, key in (("best", "best_eval"), ("final", "final_eval")):
            ev = summary.get(key)
            if ev:
                shown = {k: v for k, v in ev.items() if not k.startswith("time")}
                lines += [f"**{label} evaluation**", "", *_metric_table(shown), ""]
    lines += ["## Physical metrics", ""]
    if evaluation:
        checkpoint = Path(evaluation["checkpoint"]).name
        lines.append(
            f"Checkpoint `{checkpoint}` ({evaluation['trained_frames']:,} frames), "
            f"{evaluation['episodes']} deterministic episodes, seed {evaluation['seed']}."
        )
        lines += [
            "",
            *_metric_table(
                {"return_mean": f"{evaluation['return_mean']:.3f} ± {evaluation['return_std']:.3f}"}
            ),
        ]
        lines += _metric_table(evaluation["physical"])[2:]
        if "video" in evaluation:
            lines += [
                "",
                f"Video of the first episode: [{Path(evaluation['video']).name}]({evaluation['video']})",
            ]
    else:
        lines.append(f"Not evaluated yet: `python roto_trl/evaluate.py run={run_dir}`.")
    lines += ["", "## Training", "", "![training](plots/train.png)", ""]
    files = [p.name for p in sorted(run_dir.iterdir()) if p.name not in ("index.md", ".lock", ".lock.owner")]
    lines += ["## Files", "", ", ".join(f"`{name}`" for name in files), ""]
    out = run_dir / "index.md"
    out.write_text("\n".join(lines))
    return out
