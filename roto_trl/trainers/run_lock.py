"""One writer per run directory: an exclusive lock held for the life of the training process.

The lock is ``filelock``'s ``flock`` on ``<run dir>/.lock``: the operating system releases it when
its process dies, however it dies, so a killed run never blocks its resume. Beside it,
``.lock.owner`` names the holder (pid, host, start time) for the error a second writer gets.
"""

from __future__ import annotations

import json
import os
import socket
import time
from pathlib import Path

from filelock import FileLock, Timeout

from roto_trl.trainers.errors import RunInUse

LOCK_FILE = ".lock"
OWNER_FILE = ".lock.owner"


class RunLock:
    """Hold ``run_dir`` for this process (``with RunLock(run_dir):`` or ``acquire``/``release``).

    Raises :class:`~roto_trl.trainers.errors.RunInUse` naming the holder when another process
    holds it; acquiring never waits.
    """

    def __init__(self, run_dir: Path) -> None:
        self.run_dir = Path(run_dir)
        self._lock = FileLock(self.run_dir / LOCK_FILE, fallback_to_soft=False, preserve_lock_file=True)

    def acquire(self) -> RunLock:
        try:
            self._lock.acquire(timeout=0)
        except Timeout:
            raise RunInUse(
                f"{self.run_dir} is in use by {self.holder()}; wait for that run to end or stop it "
                "(a killed run frees it at once)"
            ) from None
        owner = {
            "pid": os.getpid(),
            "host": socket.gethostname(),
            "since": time.strftime("%Y-%m-%d %H:%M:%S"),
        }
        (self.run_dir / OWNER_FILE).write_text(json.dumps(owner) + "\n")
        return self

    def holder(self) -> str:
        """The holder as ``pid <pid> on <host> (since <time>)``, from ``.lock.owner``."""
        try:
            owner = json.loads((self.run_dir / OWNER_FILE).read_text())
            return f"pid {owner['pid']} on {owner['host']} (since {owner['since']})"
        except (OSError, ValueError, KeyError):
            return "another process"

    def release(self) -> None:
        if self._lock.is_locked:
            (self.run_dir / OWNER_FILE).unlink(missing_ok=True)
            self._lock.release()

    def __enter__(self) -> RunLock:
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()
