"""Tables computed once per machine rather than once per process: numpy arrays kept in a small cache on disk.

A few tables every fresh process builds before its first refit or estimate — the tabulated Planckian locus, the CIE
lamps on the grid, a camera's lamp-test lattices (:mod:`illumon.model.lamps`) — cost 10–50 ms each, a fifth of a
2 000-frame refit in a fresh process (issue 29). They are pure functions of their inputs, so they are kept as ``.npz``
files under :func:`cache_dir` and read back bit for bit (``numpy.save`` stores the float64 values exactly).

A file's name is a SHA-256 of the table's name, its inputs (as given by the caller) and what could make a recomputed
table differ in its last bits: the source files of the modules that compute it, the versions of numpy (its ``exp``,
``log`` and BLAS), colour-science (its tabulated data) and Python, the machine type, and the number of BLAS threads
the process uses at the time — a matrix product's sums split over threads round otherwise, so the Planckian locus of
a process whose BLAS runs two threads (the command line, ``benchmarks/real.py``) differs in its last bits from a
refit process's, which runs one (2e-15 in uv; found by this cache). So a changed source or upgraded library computes
anew, and an answer does not depend on whether a table was read or computed. Files are written to a temporary name
and renamed (readers never see a partial file); anything that fails — no cache folder, a folder that cannot be
written, a damaged file — computes the table as before and goes on. The folder is kept under :data:`MAX_BYTES`: after
each write the files least recently used (read or written; a read touches its file) go first — a lattice is ~0.6 MB
and a camera's change as its history's range moves, so without a bound a fleet's would only grow.
"""

from __future__ import annotations

import hashlib
import os
import platform
import sys
import tempfile
import threading
import zipfile
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ._blas import blas_threads

__all__ = ["CACHE_ENV", "MAX_BYTES", "cache_dir", "cached_arrays"]

CACHE_ENV = "ILLUMON_CACHE_DIR"
"""Environment variable naming the cache folder; set and empty, the cache is off (every table computed)."""

MAX_BYTES = 64 << 20
"""Size the cache folder is pruned to after each write (least recently used first): ~100 lamp lattices, the tables
of ~50 cameras."""

_sources: dict[str, bytes] = {}
_lock = threading.Lock()


def cache_dir() -> Path | None:
    """The cache folder: ``$ILLUMON_CACHE_DIR`` when set (``None`` when it is set and empty), else
    ``$XDG_CACHE_HOME/illumon`` or ``~/.cache/illumon``."""
    given = os.environ.get(CACHE_ENV)
    if given is not None:
        return Path(given) if given else None
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "illumon"


def _source_digest(path: str) -> bytes:
    """SHA-256 of a source file's bytes (read once a process)."""
    with _lock:
        hit = _sources.get(path)
    if hit is None:
        with open(path, "rb") as f:
            hit = hashlib.sha256(f.read()).digest()
        with _lock:
            _sources[path] = hit
    return hit


def _environment() -> bytes:
    import colour  # already imported by every caller of this module; its data version matters

    return "|".join((np.__version__, getattr(colour, "__version__", "?"), sys.version.split()[0],
                     platform.machine())).encode()


def _key(name: str, parts: Sequence[bytes | str | float | int], sources: Sequence[str]) -> str:
    h = hashlib.sha256(name.encode() + b"\0" + _environment() + repr(blas_threads()).encode())
    for src in sources:
        h.update(_source_digest(src))
    for p in parts:
        b = p if isinstance(p, bytes) else repr(p).encode()
        h.update(len(b).to_bytes(8, "little") + b)
    return h.hexdigest()[:40]


def cached_arrays(name: str, parts: Sequence[bytes | str | float | int], sources: Sequence[str],
                  compute: Callable[[], Sequence[NDArray]]) -> tuple[NDArray, ...]:
    """``compute()`` (a sequence of arrays), read from the disk cache when it holds it, else computed and stored.

    Parameters
    ----------
    name
        The table's name (the file's prefix).
    parts
        Everything the table depends on besides the code: arrays as ``tobytes()`` (with their shape where it is not
        implied), numbers, strings.
    sources
        Paths of the source files whose code computes the table (``__file__`` of each module involved).
    compute
        Computes the arrays.

    Returns
    -------
    tuple of numpy.ndarray
        The arrays, equal bit for bit to ``compute()``'s (dtype and shape included).
    """
    folder = cache_dir()
    if folder is None:
        return tuple(compute())
    try:
        path = folder / f"{name}-{_key(name, parts, sources)}.npz"
    except OSError:
        return tuple(compute())
    try:
        with np.load(path, allow_pickle=False) as z:
            out = tuple(z[f"a{i}"] for i in range(len(z.files)))
        try:
            os.utime(path)  # recently used: pruned last
        except OSError:
            pass
        return out
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile):
        pass  # absent or unreadable: computed below
    out = tuple(compute())
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{name}-", suffix=".npz", dir=folder)
        try:
            with os.fdopen(fd, "wb") as f:
                np.savez(f, **{f"a{i}": a for i, a in enumerate(out)})
            os.replace(tmp, path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
        _prune(folder, MAX_BYTES)
    except OSError:
        pass  # a cache that cannot be written: the table is still right
    return out


def _prune(folder: Path, max_bytes: int) -> None:
    """Delete the least recently used tables of ``folder`` until the rest fit in ``max_bytes`` (files another process
    removes meanwhile are skipped)."""
    files = []
    for f in folder.glob("*.npz"):
        try:
            st = f.stat()
        except OSError:
            continue
        files.append((st.st_mtime, st.st_size, f))
    total = sum(size for _, size, _ in files)
    for _, size, f in sorted(files, key=lambda t: t[0]):
        if total <= max_bytes:
            break
        try:
            f.unlink()
        except OSError:
            continue
        total -= size
