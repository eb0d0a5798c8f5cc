"""The service process's allocator settings (:mod:`illumon_service.memory`): a decoded frame reuses freed memory."""

from __future__ import annotations

import subprocess
import sys

import pytest

SCRIPT = """
import resource, sys, threading
import cv2, numpy as np
if sys.argv[1] == "1":
    from illumon_service.memory import tune_allocator
    assert tune_allocator()
img = (np.random.default_rng(0).random((1080, 1920, 3)) * 255).astype(np.uint8)
data = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 90])[1].tobytes()
def work():
    for _ in range(10):
        a = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
        t = cv2.resize(a, (320, 180), interpolation=cv2.INTER_AREA).astype(np.float32)
        del a, t
work()
f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(4):  # request threads come and go
    th = threading.Thread(target=work)
    th.start()
    th.join()
print((resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0) / 40)
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt: Linux only")
def test_decoded_frames_reuse_memory():
    """1920 × 1080 JPEG decodes (and a thumbnail each) in threads that come and go: ~1 950 minor page faults a decode
    with glibc's defaults (each 6 MB array mapped and zeroed anew), ~64 with :func:`tune_allocator`."""
    import os

    env = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_")}

    def faults(tuned: bool) -> float:
        out = subprocess.run([sys.executable, "-c", SCRIPT, "1" if tuned else "0"], capture_output=True, text=True,
                             env=env, check=True)
        return float(out.stdout.strip().splitlines()[-1])

    default, tuned = faults(False), faults(True)
    assert default > 1000 and tuned < 300, (default, tuned)


def test_operator_settings_win(monkeypatch: pytest.MonkeyPatch):
    """An operator's ``MALLOC_MMAP_THRESHOLD_`` (read by glibc at start) is left alone."""
    from illumon_service.memory import tune_allocator

    monkeypatch.setenv("MALLOC_MMAP_THRESHOLD_", "1048576")
    assert tune_allocator() is False
