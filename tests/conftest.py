"""Shared fixtures: measured data (skipped with a reason where absent) and small simulated histories."""

from __future__ import annotations

import atexit
import os
import shutil
import tempfile
import warnings

import pytest
from illumon.simulation import datasets

warnings.filterwarnings("ignore", module="colour")

if "ILLUMON_CACHE_DIR" not in os.environ:  # illumon._tables: a cache of this run's own, not the user's (~/.cache)
    os.environ["ILLUMON_CACHE_DIR"] = _CACHE = tempfile.mkdtemp(prefix="illumon-test-cache-")
    atexit.register(shutil.rmtree, _CACHE, True)


@pytest.fixture(scope="session")
def shared_data():
    """The measured-data folder; skips the test where ../shared/data is absent."""
    d = datasets.shared_data_dir()
    if d is None:
        pytest.skip("measured data (../shared/data or $ILLUMON_SHARED_DATA) not available")
    return d


@pytest.fixture(scope="session")
def sony_raw(shared_data):
    """The real chart photographs' sensor-RGB set (``benchmarks/real.py``, development data), measured once for the
    run; the tests that use it skip where ``../shared/data/real/sony-dolp`` is absent."""
    import real

    if not (shared_data / "real" / "sony-dolp").is_dir():
        pytest.skip("real photographs (../shared/data/real/sony-dolp) not available")
    return real.sony_raw(shared_data)


@pytest.fixture(scope="session")
def chart_free_pairs(sony_raw, shared_data):
    """The real chart / chart-free pairs (``benchmarks/real_pairs.py``), read and measured once for the run."""
    import real_pairs

    return real_pairs.pairs(shared_data)


@pytest.fixture(scope="session")
def camera_300d(shared_data):
    """Measured Canon 300D sensitivities on the grid."""
    return datasets.load_camera("Canon_300D")
