"""Stopping a run safely: SIGINT (Ctrl-C) or SIGTERM asks the training loop to stop.

The first signal lets the current iteration finish; the loop then writes ``latest.pt`` and
stops (:class:`~roto_trl.trainers.errors.TrainingInterrupted`). A second signal abandons the
iteration at once (``KeyboardInterrupt``); ``latest.pt`` then holds the last checkpoint.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import time

SIGNALS = (signal.SIGINT, signal.SIGTERM)


class StopRequests:
    """``with StopRequests() as stop:`` ... ``stop.signum`` is the first signal received, or None.

    Handlers are installed only in the main thread (elsewhere Python cannot) and restored on exit.
    """

    def __init__(self) -> None:
        self.signum: int | None = None
        self._previous: dict[int, object] = {}

    def _handle(self, signum: int, frame) -> None:
        if self.signum is not None:
            raise KeyboardInterrupt
        self.signum = signum
        name = signal.Signals(signum).name
        print(f"\n{name}: stopping after this iteration (again to stop at once)", file=sys.stderr, flush=True)

    def __enter__(self) -> StopRequests:
        if threading.current_thread() is threading.main_thread():
            for signum in SIGNALS:
                self._previous[signum] = signal.signal(signum, self._handle)
        return self

    def __exit__(self, *exc) -> None:
        for signum, handler in self._previous.items():
            signal.signal(signum, handler)


_PARENT: dict[int, int] = {}  # a process whose parent is watched -> that parent (one thread each)


def stop_with_parent(poll_seconds: float = 2.0) -> None:
    """SIGTERM this process when its parent dies (a multirun worker whose sweep was killed): a
    job in training then stops as on SIGTERM, writing ``latest.pt``; an idle worker ends. A
    daemon thread, started once per process."""
    pid = os.getpid()
    if pid in _PARENT:
        return
    parent = _PARENT[pid] = os.getppid()

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(poll_seconds)
        os.kill(pid, signal.SIGTERM)

    threading.Thread(target=watch, name="stop-with-parent", daemon=True).start()


def orphaned() -> bool:
    """Whether this process watches its parent (``stop_with_parent``) and that parent has died:
    whatever it would send back to the parent (a job's result or error) has nobody to read it."""
    parent = _PARENT.get(os.getpid())
    return parent is not None and os.getppid() != parent
