"""Shared fixtures: measured data (skipped with a reason where absent) and small simulated histories."""

from __future__ import annotations

import warnings

import pytest
from illumon.simulation import datasets

warnings.filterwarnings("ignore", module="colour")


@pytest.fixture(scope="session")
def shared_data():
    """The measured-data folder; skips the test where ../shared/data is absent."""
    d = datasets.shared_data_dir()
    if d is None:
        pytest.skip("measured data (../shared/data or $ILLUMON_SHARED_DATA) not available")
    return d


@pytest.fixture(scope="session")
def camera_300d(shared_data):
    """Measured Canon 300D sensitivities on the grid."""
    return datasets.load_camera("Canon_300D")
