"""Metrics of a run: CSV files always, plus one optional backend (wandb offline, tensorboard).

Each kind of row (``train``, ``eval``, ``aux``) goes to its own ``<kind>.csv`` in the run
directory, ``frames`` first. A key that first appears in a later row (an episode metric once the
first episode ends) adds a column: the file is rewritten with the wider header and the earlier
rows leave that cell empty (read back as NaN), so every metric logged reaches the CSV.

On resume every CSV is cut back to the checkpoint's frame count (:func:`truncate_csv_logs`), so
a resumed run reads as one uninterrupted run; TensorBoard hides its later events (``purge_step``);
wandb keeps what it has (docs/training.md).
"""

from __future__ import annotations

import contextlib
import csv
import math
import os
from pathlib import Path
from typing import Any

from roto_trl.trainers.errors import WriteError

BACKENDS = ("wandb", "tensorboard", "csv", "none")
KINDS = ("train", "eval", "aux")  # the CSV files a training run writes


class MetricLogger:
    """Write scalar metrics of a run.

    Args:
        run_dir: the run's directory.
        backend: ``wandb`` (offline: works without network; sync later with ``wandb sync``),
            ``tensorboard``, ``csv`` or ``none`` (both: CSV files only).
        config: the run's config, recorded by the backend.
        name, project: the run's name and the wandb project.
        resume_frames: the checkpoint's frame count when the run resumes (None: a new run). The
            CSV files are appended to (cut back to it first with :func:`truncate_csv_logs`) and
            TensorBoard hides the events logged after it.
    """

    def __init__(
        self,
        run_dir: Path,
        backend: str,
        *,
        config: dict | None = None,
        name: str = "",
        project: str = "roto-trl",
        resume_frames: int | None = None,
    ) -> None:
        if backend not in BACKENDS:
            raise ValueError(f"logger.backend must be one of {list(BACKENDS)}, got {backend!r}")
        self.run_dir = Path(run_dir)
        self.backend = backend
        self._files: dict[str, Any] = {}
        self._writers: dict[str, csv.DictWriter] = {}
        self._resume = resume_frames is not None
        self._wandb = self._tb = None
        if backend == "wandb":
            import wandb

            self._wandb = wandb.init(
                project=project,
                name=name,
                dir=str(self.run_dir),
                config=config,
                mode="offline",
                resume="allow" if self._resume else None,
                id=self.run_dir.name.replace("/", "-") if self._resume else None,
                settings=wandb.Settings(console="off", silent=True),
            )
        elif backend == "tensorboard":
            from torch.utils.tensorboard import SummaryWriter

            # events at steps past the checkpoint, from before the resume, are hidden
            purge = None if resume_frames is None else int(resume_frames) + 1
            self._tb = SummaryWriter(log_dir=str(self.run_dir / "tensorboard"), purge_step=purge)

    def log(self, kind: str, metrics: dict[str, float], step: int, *, csv_only: bool = False) -> None:
        """Record ``metrics`` (scalars) of ``kind`` at ``step`` (env frames).

        ``csv_only`` keeps fine-grained rows (one per minibatch) out of the backend. A failed
        write (a full disk) raises :class:`~roto_trl.trainers.errors.WriteError` naming the file.
        """
        row = {"frames": int(step), **{k: float(v) for k, v in metrics.items()}}
        try:
            writer = self._writers.get(kind) or self._open(kind, list(row))
            new = [key for key in row if key not in writer.fieldnames]
            if new:
                writer = self._widen(kind, new)
            writer.writerow(row)
            self._files[kind].flush()
        except OSError as err:
            raise WriteError(f"cannot write {self.run_dir / f'{kind}.csv'}: {err.strerror.lower()}") from None
        if csv_only:
            return
        finite = {f"{kind}/{k}": v for k, v in row.items() if k != "frames" and math.isfinite(v)}
        if self._wandb is not None:
            self._wandb.log(finite, step=int(step))
        if self._tb is not None:
            for key, value in finite.items():
                self._tb.add_scalar(key, value, int(step))

    def _open(self, kind: str, fields: list[str]) -> csv.DictWriter:
        path = self.run_dir / f"{kind}.csv"
        append = self._resume and path.is_file() and path.stat().st_size > 0
        if append:
            fields = _header(path)
        handle = path.open("a" if append else "w", newline="")
        writer = csv.DictWriter(handle, fieldnames=fields)
        if not append:
            writer.writeheader()
        self._files[kind], self._writers[kind] = handle, writer
        return writer

    def _widen(self, kind: str, new: list[str]) -> csv.DictWriter:
        """Rewrite ``<kind>.csv`` with ``new`` columns added (earlier rows leave them empty)."""
        fields = [*self._writers[kind].fieldnames, *new]
        self._files.pop(kind).close()
        path = self.run_dir / f"{kind}.csv"
        with path.open(newline="") as handle:
            rows = list(csv.DictReader(handle))
        tmp = path.with_name(path.name + ".tmp")
        with tmp.open("w", newline="") as handle:
            writer = csv.DictWriter(handle, fieldnames=fields)
            writer.writeheader()
            writer.writerows(rows)
        os.replace(tmp, path)
        handle = path.open("a", newline="")
        self._files[kind] = handle
        self._writers[kind] = csv.DictWriter(handle, fieldnames=fields)
        return self._writers[kind]

    def truncate(self, frames: int) -> None:
        """Cut every CSV back to ``frames`` (after a failed checkpoint: the logs then match the
        last good one); later rows reopen the files."""
        for handle in self._files.values():
            handle.close()
        self._files.clear()
        self._writers.clear()
        self._resume = True
        truncate_csv_logs(self.run_dir, frames)

    def close(self) -> None:
        for handle in self._files.values():
            with contextlib.suppress(OSError):  # the buffered row of a failed write: log() reported it
                handle.close()
        if self._wandb is not None:
            self._wandb.finish()
        if self._tb is not None:
            self._tb.close()


def _header(path: Path) -> list[str]:
    with path.open(newline="") as handle:
        return next(csv.reader(handle))


def truncate_csv(path: Path, frames: int) -> int:
    """Drop the rows of a metrics CSV from the first one past ``frames`` (or the first one
    half-written by a killed process); returns how many.

    Cut in place (``os.truncate``): it needs no free disk space, so it also works on a full disk;
    read line by line, so a long run's log is never held in memory.
    """
    with Path(path).open("rb") as handle:
        offset = len(handle.readline())  # the header
        for line in handle:
            try:
                row_frames = float(line.split(b",", 1)[0])
            except ValueError:
                row_frames = math.inf
            if not line.endswith(b"\n") or row_frames > frames:
                dropped = 1 + sum(1 for _ in handle)
                os.truncate(path, offset)
                return dropped
            offset += len(line)
    return 0


def truncate_csv_logs(run_dir: Path, frames: int) -> dict[str, int]:
    """Cut ``train.csv``, ``eval.csv`` and ``aux.csv`` of a run back to ``frames``; the rows
    dropped per file."""
    dropped = {}
    for kind in KINDS:
        path = Path(run_dir) / f"{kind}.csv"
        if path.is_file():
            dropped[kind] = truncate_csv(path, frames)
    return dropped


def read_csv(path: Path) -> dict[str, list[float]]:
    """Columns of a metrics CSV as lists of floats (empty cells read as NaN); ``{}`` for a file
    without rows. A last line cut short (a kill in the middle of writing it: no line end) is left
    out (``cut_last_line`` tells)."""
    with Path(path).open(newline="") as handle:
        text = handle.read()
    if text and not text.endswith("\n"):
        text = text[: text.rfind("\n") + 1]
    rows = list(csv.DictReader(text.splitlines()))
    if not rows:
        return {}
    return {k: [float(r[k]) if r[k] not in ("", None) else math.nan for r in rows] for k in rows[0]}


def cut_last_line(path: Path) -> bool:
    """Whether a metrics CSV ends in a line cut short (no line end: a kill in the middle of it)."""
    path = Path(path)
    if not path.is_file() or path.stat().st_size == 0:
        return False
    with path.open("rb") as handle:
        handle.seek(-1, os.SEEK_END)
        return handle.read(1) != b"\n"
