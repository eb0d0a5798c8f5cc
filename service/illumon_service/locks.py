"""Process locks on the data directory: which of the service processes sharing it runs a periodic task."""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["take_process_lock"]


def take_process_lock(path: Path | str) -> tuple[bool, int | None]:
    """Try to hold an exclusive ``flock`` on ``path`` (created 0600), released when the process ends or the returned
    descriptor is closed.

    Returns
    -------
    held, fd
        ``(True, fd)`` when this process holds it, ``(False, None)`` when another does; ``(True, None)`` where
        ``flock`` does not exist (not POSIX: one process per data directory assumed).
    """
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not on POSIX
        return True, None
    fd = os.open(Path(path), os.O_RDWR | os.O_CREAT, 0o600)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        os.close(fd)
        return False, None
    return True, fd
