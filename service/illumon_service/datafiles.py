"""Files under the data directory that the database refers to (frame thumbnails, kept images).

The database stores them relative to the data directory (``thumbs/camera-3/118.png``), so that a copy of the
database and the data directory — a backup restored elsewhere, a data directory moved — refers to its own files,
never to the original's (which it would otherwise read, and prune). Versions before this stored absolute paths:
:func:`.crud.relativize_paths` rewrites those at start-up and in every backup.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path, PurePath

from .storage import Frame

__all__ = ["PATH_COLUMNS", "atomic_write", "stored_path", "data_file", "relative_form"]

PATH_COLUMNS = (Frame.thumb_path, Frame.image_path)
"""The columns holding paths of files under the data directory."""

_TOP_FOLDERS = ("thumbs", "images")
"""The data directory's folders such paths lie in (``<folder>/camera-<id>/<file>``)."""


def atomic_write(path: Path, data: bytes | bytearray) -> None:
    """Write ``data`` to ``path`` through a private temporary file in the same folder, renamed into place: readers
    see the old file or the new one, and concurrent writers never share a temporary file."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def stored_path(data_dir: Path | str, path: Path | str) -> str:
    """The form of ``path`` (a file under ``data_dir``) stored in the database: relative to ``data_dir``, POSIX
    separators.

    Raises
    ------
    ValueError
        ``path`` does not lie under ``data_dir``.
    """
    path = Path(path)
    base = Path(data_dir)
    if not path.is_absolute():
        path = base / path
    return path.resolve().relative_to(base.resolve()).as_posix()


def data_file(data_dir: Path | str, stored: str | None) -> Path | None:
    """The file a stored path names under ``data_dir`` (``None`` for none). A path that is absolute or leaves the
    data directory (``..``) names no file here: ``None``, so that nothing outside the data directory is ever read or
    deleted through the database."""
    if not stored:
        return None
    rel = PurePath(stored)
    if rel.is_absolute() or ".." in rel.parts:
        return None
    return Path(data_dir) / rel


def relative_form(data_dir: Path | str, stored: str) -> str | None:
    """The relative form of an absolute stored path: relative to ``data_dir`` when it lies there, else its tail from
    the last ``thumbs/camera-<id>/`` or ``images/camera-<id>/`` (a data directory that was moved or copied);
    ``None`` when neither applies. A relative path is returned unchanged."""
    p = PurePath(stored)
    if not p.is_absolute():
        return stored
    try:
        return stored_path(data_dir, Path(stored))
    except ValueError:
        pass
    parts = p.parts
    for i in range(len(parts) - 3, -1, -1):
        if parts[i] in _TOP_FOLDERS and parts[i + 1].startswith("camera-"):
            return PurePath(*parts[i:]).as_posix()
    return None
