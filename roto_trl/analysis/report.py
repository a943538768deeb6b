"""A run's report: ``index.md`` in the run directory, one file that shows how the run went.

It embeds the plots (``plots/eval.png``, ``plots/train.png``) and tabulates ``summary.json``
(frames, wall time, best and final evaluation) and ``eval.json`` (the physical metrics of the
best checkpoint, written by ``roto_trl/evaluate.py``). Missing pieces (a run still going, a run
never evaluated) are said so, not skipped silently.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from roto_trl.analysis.runs import read_json


def _table(rows: dict[str, Any]) -> list[str]:
    lines = ["| | |", "|---|---|"]
    for key, value in rows.items():
        shown = (
            f"{value:,.4g}" if isinstance(value, float) else f"{value:,}" if isinstance(value, int) else value
        )
        lines.append(f"| {key} | {shown} |")
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
                "frames / s": summary["frames_per_s"] or 0.0,
            }
        )
    else:
        lines.append("No `summary.json` yet: the run has not finished.")
    lines += ["", "## Evaluation", "", "![evaluation](plots/eval.png)", ""]
    if summary:
        for label, key in (("best", "best_eval"), ("final", "final_eval")):
            ev = summary.get(key)
            if ev:
                shown = {k: v for k, v in ev.items() if k != "time"}
                lines += [f"**{label} evaluation**", "", *_table(shown), ""]
    lines += ["## Physical metrics", ""]
    if evaluation:
        checkpoint = Path(evaluation["checkpoint"]).name
        lines.append(
            f"Checkpoint `{checkpoint}` ({evaluation['trained_frames']:,} frames), "
            f"{evaluation['episodes']} deterministic episodes, seed {evaluation['seed']}."
        )
        lines += [
            "",
            *_table({"return": f"{evaluation['return_mean']:.3f} ± {evaluation['return_std']:.3f}"}),
        ]
        lines += _table(evaluation["physical"])[2:]
        if "video" in evaluation:
            lines += [
                "",
                f"Video of the first episode: [{Path(evaluation['video']).name}]({evaluation['video']})",
            ]
    else:
        lines.append(f"Not evaluated yet: `python roto_trl/evaluate.py run={run_dir}`.")
    lines += ["", "## Training", "", "![training](plots/train.png)", ""]
    files = [p.name for p in sorted(run_dir.iterdir()) if p.name != "index.md"]
    lines += ["## Files", "", ", ".join(f"`{name}`" for name in files), ""]
    out = run_dir / "index.md"
    out.write_text("\n".join(lines))
    return out
