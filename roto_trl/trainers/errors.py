"""Errors a training run reports in one line instead of a traceback, with the exit status of each
(``exit_with_report``), the report of a multirun job that failed (``report_failed_job``), and
the end of a job whose launcher died (``end_orphaned_job``)."""

import os
import sys
import traceback
from pathlib import Path
from typing import NoReturn


class NonFiniteError(RuntimeError):
    """A loss, gradient, parameter or return estimate became NaN or inf. ``run_dir`` and
    ``saved_frames`` (what ``latest.pt`` holds, None without a checkpoint) are set by the loop
    that stopped, for its one-line report."""

    run_dir = None
    saved_frames: int | None = None

    @property
    def what_now(self) -> str:
        """What the run left and what to do, for the report after the error's own line."""
        if self.saved_frames:
            return (
                f"The last good checkpoint ({self.saved_frames:,} frames) is intact; after fixing the cause, "
                f"continue with: python roto_trl/train.py resume={self.run_dir}"
            )
        return "No checkpoint was written before it; fix the cause and start the run again with its command"


class DivergedError(NonFiniteError):
    """The run diverged (``trainers.divergence``) for ``divergence.stop_after`` iterations in a row."""


class RunInUse(RuntimeError):
    """Another live process holds the run directory (exit status 2)."""


class WriteError(RuntimeError):
    """A run file could not be written (a full disk); the logs are cut back to the last
    checkpoint (exit status 1)."""


class TrainingInterrupted(KeyboardInterrupt):
    """SIGINT or SIGTERM stopped the run; ``latest.pt`` holds ``frames`` (exit status 128 + signal).

    A ``KeyboardInterrupt``, so that whatever stops on Ctrl-C (a sweep) stops on it too.
    """

    def __init__(self, frames: int, signum: int, run_dir) -> None:
        super().__init__(f"stopped at {frames:,} frames")
        self.frames, self.signum, self.run_dir = frames, signum, run_dir

    def __reduce__(self):
        # a multirun's job sends its error back to the launcher pickled: rebuilt from its fields
        return type(self), (self.frames, self.signum, self.run_dir)


# a single run's exit status and one-line message for each error it reports (``train.py``'s main)
EXIT_STATUS: dict[type[BaseException], tuple[int, str]] = {
    NonFiniteError: (3, "stopped: {err}. {err.what_now}"),
    WriteError: (1, "{err}"),
    RunInUse: (2, "{err}"),
    ValueError: (2, "{err}"),
    FileNotFoundError: (2, "{err}"),
    FileExistsError: (2, "{err}"),
}


def one_line_report(err: BaseException) -> tuple[int, str] | None:
    """The exit status and one-line report of a run stopped by ``err``; None for an error that is
    not one of ours (a bug, which keeps its traceback)."""
    if isinstance(err, TrainingInterrupted):
        resume = f"continue with: python roto_trl/train.py resume={err.run_dir}"
        what = (
            f"stopped at {err.frames:,} frames; {resume}"
            if err.frames
            else "stopped before the first checkpoint"
        )
        return 128 + err.signum, f"train: {what}"
    if isinstance(err, KeyboardInterrupt):  # before the loop's handlers were installed, or after it
        return 130, "train: interrupted"
    for kind, (status, message) in EXIT_STATUS.items():
        if isinstance(err, kind):
            return status, f"train: {message.format(err=err)}"
    return None


def exit_with_report(err: BaseException) -> None:
    """End a single run stopped by ``err`` with its one-line report on stderr and its exit status;
    an error that is not one of ours is raised again, traceback and all (a bug to report)."""
    report = one_line_report(err)
    if report is None:
        raise err
    status, line = report
    print(line, file=sys.stderr)
    sys.exit(status)


def end_orphaned_job(err: BaseException | None) -> NoReturn:
    """End the process of a multirun job whose launcher has died (``interrupts.orphaned``), after
    its one-line report (``err`` None: the job finished). Returning or raising would send the
    result to a launcher no longer there, and the worker would wait for it forever."""
    if err is None:
        status, line = 0, "train: finished; its launcher had stopped"
    else:  # a bug has its traceback in error.txt already (report_failed_job)
        status, line = one_line_report(err) or (1, f"train: failed: {type(err).__name__}")
    try:
        print(line, file=sys.stderr)
        sys.stdout.flush()
        sys.stderr.flush()
    finally:
        os._exit(status)  # not sys.exit: the worker's pool would catch it and wait on the parent


def report_failed_job(cfg, err: BaseException) -> None:
    """A multirun job failed: its traceback to ``<run_dir>/error.txt`` and one line naming the job,
    so that every failed job is reported (Hydra's own traceback names only the first)."""
    run_dir = Path(str(cfg.run_dir or cfg.resume or "."))
    where = ""
    if run_dir.is_dir():
        (run_dir / "error.txt").write_text("".join(traceback.format_exception(err)))
        where = f" (traceback in {run_dir / 'error.txt'})"
    first = (str(err).strip().splitlines() or [""])[0][:300]
    print(
        f"train: the job in {run_dir} failed: {type(err).__name__}: {first}{where}",
        file=sys.stderr,
        flush=True,
    )
