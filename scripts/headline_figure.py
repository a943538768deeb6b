"""The README's headline figure: our learning curves against the authors', per task.

    .venv/bin/python scripts/headline_figure.py 'runs/study/find/find_ppo-s*' \\
        'runs/study/bounce/bounce_ppo-s*' 'runs/baoding/baoding_ppo-s1?' --out docs/headline.png

One panel per task among the runs given: the task's headline metric of each experiment's
evaluations against frames (the mean over seeds, a band from its lowest to highest seed), and
beside it the authors' mean and best seed over their whole runs
(``assets/reference/authors_curves.csv``; theirs at 4096 worlds, an evaluation every 2.5 M
frames up to 200-250 M). The frames axis is logarithmic, so that ours (2-10 M) and theirs share
it and a reader sees at which of their frame counts they reached what ours reach. Runs are read
and grouped as the analysis tools do (``analysis.runs``).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.ticker import NullFormatter

from roto_trl.analysis.metrics import describe
from roto_trl.analysis.plots import FRAMES, save_figure
from roto_trl.analysis.runs import by_experiment, countable, find_runs, headline_of
from roto_trl.analysis.table import load_reference, reference_curve
from roto_trl.trainers.loggers import read_csv


def seed_band(curves: list[dict[str, list[float]]], metric: str) -> tuple[np.ndarray, ...]:
    """Seeds' evaluation curves on common frames: ``(frames, mean, lowest, highest)``, each ``[F]``.

    ``frames`` are every seed's evaluation frames up to the shortest run's last, and each curve is
    interpolated onto them, so a band never runs past a seed that did not get there."""
    last = min(c["frames"][-1] for c in curves)
    frames = np.unique(np.concatenate([[f for f in c["frames"] if f <= last] for c in curves]))
    values = np.stack([np.interp(frames, c["frames"], c[metric]) for c in curves])
    return frames, values.mean(0), values.min(0), values.max(0)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("runs", nargs="+", help="run directories or quoted globs, any tasks")
    parser.add_argument("--out", type=Path, default=Path("docs/headline.png"))
    parser.add_argument("--unfinished", action="store_true", help="draw runs still going too")
    args = parser.parse_args(argv)
    runs = countable(find_runs(args.runs), "headline", unfinished=args.unfinished)
    tasks = list(dict.fromkeys(r.task for r in runs))
    reference = load_reference()
    fig, axes = plt.subplots(1, len(tasks), figsize=(5.2 * len(tasks), 3.9), squeeze=False)
    for ax, task in zip(axes[0], tasks, strict=True):
        members = [r for r in runs if r.task == task]
        headline = headline_of(members[0].path)
        for i, (group, group_runs) in enumerate(by_experiment(members).items()):
            frames, mean, low, high = seed_band([read_csv(r.path / "eval.csv") for r in group_runs], headline)
            drawn = frames > 0  # a log axis has no 0: the untrained policy's point is left out
            frames, mean, low, high = frames[drawn], mean[drawn], low[drawn], high[drawn]
            seeds = f"{len(group_runs)} seed{'s' if len(group_runs) > 1 else ''}"
            ax.plot(frames, mean, color=f"C{i}", label=f"ours: {group} ({seeds})")
            ax.fill_between(frames, low, high, color=f"C{i}", alpha=0.15)
            theirs = reference_curve(reference, group_runs[0].exp_name, headline)
            if theirs:
                at, their_mean, best = theirs
                exp = group_runs[0].exp_name
                ax.plot(at, their_mean, "x--", color=f"C{i}", linewidth=0.8, label=f"authors: {exp}, mean")
                ax.plot(at, best, ":", color=f"C{i}", linewidth=0.8, label=f"authors: {exp}, best seed")
        name, unit = describe(headline)
        ax.set(title=f"{task}: {name}", xlabel="frames", ylabel=unit or name)
        ax.set_xscale("log")
        ax.xaxis.set_major_formatter(FRAMES)
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.legend(fontsize=7)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    print(save_figure(fig, args.out, dpi=110).resolve())
    return 0


if __name__ == "__main__":
    sys.exit(main())
