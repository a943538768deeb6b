"""Plots of a run from its CSV files: evaluation return and metrics, training reward."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only, no display
import matplotlib.pyplot as plt
import numpy as np

from roto_trl.trainers.loggers import read_csv

SKIP = {"frames", "iteration", "return_mean", "return_std", "time"}


def save_figure(fig, path: Path, dpi: int = 100) -> Path:
    """Lay out ``fig``, write it to ``path`` and free it; returns ``path``."""
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path


def plot_run(run_dir: Path) -> list[Path]:
    """Write ``plots/eval.png`` and ``plots/train.png`` for the run; returns the files written."""
    run_dir = Path(run_dir)
    out = run_dir / "plots"
    out.mkdir(exist_ok=True)
    written = []
    if (run_dir / "eval.csv").is_file():
        ev = read_csv(run_dir / "eval.csv")
        metrics = [k for k in ev if k not in SKIP]
        fig, axes = plt.subplots(1, 1 + len(metrics), figsize=(4.5 * (1 + len(metrics)), 3.5), squeeze=False)
        x = np.asarray(ev["frames"])
        mean, std = np.asarray(ev["return_mean"]), np.asarray(ev["return_std"])
        axes[0, 0].plot(x, mean, marker="o")
        axes[0, 0].fill_between(x, mean - std, mean + std, alpha=0.25)
        axes[0, 0].set(title="evaluation return (mean ± std)", xlabel="frames")
        for ax, key in zip(axes[0, 1:], metrics, strict=True):
            ax.plot(x, ev[key], marker="o")
            ax.set(title=f"evaluation {key}", xlabel="frames")
        written.append(save_figure(fig, out / "eval.png"))
    if (run_dir / "train.csv").is_file():
        tr = read_csv(run_dir / "train.csv")
        keys = [k for k in ("reward", "episode_return", "loss_critic", "entropy") if k in tr]
        fig, axes = plt.subplots(1, len(keys), figsize=(4.5 * len(keys), 3.5), squeeze=False)
        for ax, key in zip(axes[0], keys, strict=True):
            ax.plot(tr["frames"], tr[key])
            ax.set(title=f"training {key}", xlabel="frames")
        written.append(save_figure(fig, out / "train.png"))
    return written
