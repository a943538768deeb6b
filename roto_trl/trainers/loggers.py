"""Metrics of a run: CSV files always, plus one optional backend (wandb offline, tensorboard).

Each kind of row (``train``, ``eval``) goes to its own ``<kind>.csv`` in the run directory; its
columns are those of its first row (later rows must have the same keys, missing ones stay empty).
"""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Any

BACKENDS = ("wandb", "tensorboard", "csv", "none")


class MetricLogger:
    """Write scalar metrics of a run.

    Args:
        run_dir: the run's directory.
        backend: ``wandb`` (offline: works without network; sync later with ``wandb sync``),
            ``tensorboard``, ``csv`` or ``none`` (both: CSV files only).
        config: the run's config, recorded by the backend.
        name, project: the run's name and the wandb project.
        resume: append to existing CSV files instead of starting them.
    """

    def __init__(
        self,
        run_dir: Path,
        backend: str,
        *,
        config: dict | None = None,
        name: str = "",
        project: str = "roto-trl",
        resume: bool = False,
    ) -> None:
        if backend not in BACKENDS:
            raise ValueError(f"logger.backend must be one of {list(BACKENDS)}, got {backend!r}")
        self.run_dir = Path(run_dir)
        self.backend = backend
        self._files: dict[str, Any] = {}
        self._writers: dict[str, csv.DictWriter] = {}
        self._resume = resume
        self._wandb = self._tb = None
        if backend == "wandb":
            import wandb

            self._wandb = wandb.init(
                project=project,
                name=name,
                dir=str(self.run_dir),
                config=config,
                mode="offline",
                resume="allow" if resume else None,
                id=self.run_dir.name.replace("/", "-") if resume else None,
                settings=wandb.Settings(console="off", silent=True),
            )
        elif backend == "tensorboard":
            from torch.utils.tensorboard import SummaryWriter

            self._tb = SummaryWriter(log_dir=str(self.run_dir / "tensorboard"))

    def log(self, kind: str, metrics: dict[str, float], step: int, *, csv_only: bool = False) -> None:
        """Record ``metrics`` (scalars) of ``kind`` at ``step`` (env frames).

        ``csv_only`` keeps fine-grained rows (one per minibatch) out of the backend.
        """
        row = {"frames": int(step), **{k: float(v) for k, v in metrics.items()}}
        writer = self._writers.get(kind)
        if writer is None:
            path = self.run_dir / f"{kind}.csv"
            append = self._resume and path.is_file()
            fields = _header(path) if append else list(row)
            handle = path.open("a" if append else "w", newline="")
            writer = csv.DictWriter(handle, fieldnames=fields, extrasaction="ignore")
            if not append:
                writer.writeheader()
            self._files[kind], self._writers[kind] = handle, writer
        writer.writerow(row)
        self._files[kind].flush()
        if csv_only:
            return
        finite = {f"{kind}/{k}": v for k, v in row.items() if k != "frames" and math.isfinite(v)}
        if self._wandb is not None:
            self._wandb.log(finite, step=int(step))
        if self._tb is not None:
            for key, value in finite.items():
                self._tb.add_scalar(key, value, int(step))

    def close(self) -> None:
        for handle in self._files.values():
            handle.close()
        if self._wandb is not None:
            self._wandb.finish()
        if self._tb is not None:
            self._tb.close()


def _header(path: Path) -> list[str]:
    with path.open(newline="") as handle:
        return next(csv.reader(handle))


def read_csv(path: Path) -> dict[str, list[float]]:
    """Columns of a metrics CSV as lists of floats (empty cells read as NaN)."""
    with Path(path).open(newline="") as handle:
        rows = list(csv.DictReader(handle))
    if not rows:
        return {}
    return {k: [float(r[k]) if r[k] not in ("", None) else math.nan for r in rows] for k in rows[0]}
