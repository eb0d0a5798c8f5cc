"""The memory allocator of a service process: a decoded frame reuses freed memory instead of faulting in fresh pages.

A 1920 × 1080 frame decodes into a 6 MB array. glibc serves an allocation that large with ``mmap`` and gives it back
with ``munmap`` when it is freed (its dynamic threshold rises only for the arena that freed it, and the request
threads come from a pool, so most decodes missed it), and it trims the free top of a heap back to the system: the
next frame's pixels were then written into pages the kernel had to map and zero first — ~1 950 minor page faults per
decode (a decode-and-thumbnail loop in four threads), ~64 with the thresholds below. Measured on the ingest path
(``nice python benchmarks/ingest.py --concurrency 1 --jpeg-reduction 1 --frames 120``, JPEG, one client, load ~1):
the server's ``decode`` stage 4.7–4.9 ms a frame against 3.5 ms for ``decode_frame`` of the same files in a loop,
3.6–3.7 ms with the thresholds (server CPU 13.7 → 12.0–13.3 ms a frame, ratio to decode-only 0.28–0.29 →
0.30–0.33). The thresholds keep allocations up to :data:`MMAP_THRESHOLD` in the heaps and at most
:data:`TRIM_THRESHOLD` of free memory at a heap's top: a bounded amount held, not a leak.

Set only on glibc (``mallopt``), and not where the operator set ``MALLOC_MMAP_THRESHOLD_`` or
``MALLOC_TRIM_THRESHOLD_`` in the environment (those win, as glibc reads them at start).
"""

from __future__ import annotations

import ctypes
import os
import sys

__all__ = ["MMAP_THRESHOLD", "TRIM_THRESHOLD", "tune_allocator"]

MMAP_THRESHOLD = 32 << 20
"""Bytes from which an allocation is its own ``mmap`` (glibc's dynamic threshold stops at 32 MiB on 64-bit systems
too): a 4K 8-bit frame (24 MB) and every smaller image stay in the heap."""

TRIM_THRESHOLD = 64 << 20
"""Bytes of free memory at a heap's top above which glibc returns it to the system."""

_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3  # glibc's mallopt parameters (malloc.h)


def tune_allocator() -> bool:
    """Set glibc's mmap and trim thresholds for this process (module docstring); ``True`` if they were set."""
    if not sys.platform.startswith("linux"):
        return False
    if "MALLOC_MMAP_THRESHOLD_" in os.environ or "MALLOC_TRIM_THRESHOLD_" in os.environ:
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):  # not glibc
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    return bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD)) and bool(mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD))
