"""Where programs write: checked before any work, so a bad path costs seconds, not a run."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path


def writable_dir(path: Path, key: str) -> Path:
    """``path`` as a directory this process can write in, created if needed; otherwise a
    one-line ``ValueError`` naming ``key``, the path and why."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise ValueError(f"{key}={path} is a file, not a directory; give a directory path")
    try:
        path.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=path):
            pass
    except OSError as err:
        raise ValueError(
            f"{key}={path} is not writable ({err.strerror}); give a directory you can write"
        ) from None
    return path


def writable_file(path: Path, key: str) -> Path:
    """``path`` as a file this process can write (its directory created if needed, an existing
    file left as it is); otherwise a one-line ``ValueError`` naming ``key``, the path and why."""
    path = Path(path)
    if path.is_dir():
        raise ValueError(f"{key}={path} is a directory; give a file name")
    writable_dir(path.parent, key)
    if path.exists() and not os.access(path, os.W_OK):
        raise ValueError(f"{key}={path} is not writable; give another file name")
    return path
