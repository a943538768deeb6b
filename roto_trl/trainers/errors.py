"""Errors a training run reports in one line instead of a traceback (``train.py`` maps each to
its exit status)."""


class NonFiniteError(RuntimeError):
    """A loss, gradient, parameter or return estimate became NaN or inf."""


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
