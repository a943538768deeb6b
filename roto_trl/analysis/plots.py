"""A run's own plots from its CSV files: ``plots/eval.png`` (the evaluations: the task's headline
metric first, the return, the other physical metrics) and ``plots/train.png`` (the training
episodes, losses and step sizes), each a grid of labelled panels."""

from __future__ import annotations

import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only, no display
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.ticker import FuncFormatter

from roto_trl.analysis.metrics import describe
from roto_trl.analysis.runs import headline_of
from roto_trl.trainers.loggers import read_csv
from roto_trl.utils.cli import frames_label

FRAMES = FuncFormatter(lambda value, _: frames_label(round(value)) if value > 0 else "0")  # 1.5M, 400k
EVAL_SKIP = {"frames", "iteration", "return_mean", "return_std", "time"}
TRAIN_PANELS = (
    "episode_return",
    "reward",
    "loss_critic",
    "entropy",
    "kl_k3_median",
    "clip_fraction_median",
    "lr",
    "fps",
)
COLUMNS = 3


def save_figure(fig, path: Path, dpi: int = 100) -> Path:
    """Lay out ``fig``, write it to ``path`` and free it; returns ``path``."""
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path


def grid(panels: int, title: str):
    """A figure of ``panels`` axes, ``COLUMNS`` to a row, the unused ones hidden."""
    rows = max(1, math.ceil(panels / COLUMNS))
    cols = min(COLUMNS, max(1, panels))
    fig, axes = plt.subplots(rows, cols, figsize=(4.6 * cols, 3.4 * rows), squeeze=False)
    for ax in axes.flat[panels:]:
        ax.set_visible(False)
    fig.suptitle(title)
    return fig, list(axes.flat[:panels])


def panel(ax, x, y, key: str, *, band=None) -> None:
    """One series against frames: markers on every point that has a value (a series logged on
    few iterations stays visible), lines between them, an optional ± band."""
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    has = np.isfinite(y)
    ax.plot(x[has], y[has], marker="o", markersize=3)
    if band is not None:
        spread = np.asarray(band, dtype=float)[has]
        ax.fill_between(x[has], y[has] - spread, y[has] + spread, alpha=0.25)
    name, unit = describe(key)
    ax.set(
        title=name + (" (mean ± std)" if band is not None else ""), xlabel="frames", ylabel=unit or "value"
    )
    ax.xaxis.set_major_formatter(FRAMES)
    if not has.any():
        ax.text(0.5, 0.5, "not logged yet", ha="center", va="center", transform=ax.transAxes)


def plot_run(run_dir: Path) -> list[Path]:
    """Write ``plots/eval.png`` and ``plots/train.png`` for the run; returns the files written."""
    run_dir = Path(run_dir)
    out = run_dir / "plots"
    out.mkdir(exist_ok=True)
    headline = headline_of(run_dir)
    written = []
    if (run_dir / "eval.csv").is_file():
        ev = read_csv(run_dir / "eval.csv")
        if ev.get("frames"):
            metrics = [k for k in ev if k not in EVAL_SKIP]
            if headline in metrics:  # the task's headline first, then the return
                metrics.remove(headline)
                metrics.insert(0, headline)
            fig, axes = grid(1 + len(metrics), f"{run_dir.name}: evaluations (deterministic policy)")
            order = (
                [*metrics[:1], "return_mean", *metrics[1:]] if headline in ev else ["return_mean", *metrics]
            )
            for ax, key in zip(axes, order, strict=True):
                band = ev["return_std"] if key == "return_mean" and "return_std" in ev else None
                panel(ax, ev["frames"], ev[key], key, band=band)
            written.append(save_figure(fig, out / "eval.png"))
    if (run_dir / "train.csv").is_file():
        tr = read_csv(run_dir / "train.csv")
        keys = [k for k in (f"episode/{headline}", *TRAIN_PANELS) if k in tr]
        if tr.get("frames") and keys:
            fig, axes = grid(len(keys), f"{run_dir.name}: training (sampled policy, per iteration)")
            for ax, key in zip(axes, keys, strict=True):
                panel(ax, tr["frames"], tr[key], key)
            written.append(save_figure(fig, out / "train.png"))
    return written
