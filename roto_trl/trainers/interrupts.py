"""Stopping a run safely: SIGINT (Ctrl-C) or SIGTERM asks the training loop to stop.

The first signal lets the current iteration finish; the loop then writes ``latest.pt`` and
stops (:class:`~roto_trl.trainers.errors.TrainingInterrupted`). A second signal abandons the
iteration at once (``KeyboardInterrupt``); ``latest.pt`` then holds the last checkpoint.
"""

from __future__ import annotations

import signal
import sys
import threading

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
