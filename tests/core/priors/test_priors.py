"""Priors built from measured data: the shipped camera and daylight priors load, and a rebuilt camera prior leaves
the held-out camera out."""

import numpy as np
import pytest
from illumon.priors import build_camera_prior, default_camera_prior, default_daylight_prior
from illumon.simulation import datasets

needs_data = pytest.mark.skipif(
    datasets.shared_data_dir() is None, reason="measured data (../shared/data) not available"
)


def test_shipped_priors_load():
    cp = default_camera_prior()
    dp = default_daylight_prior()
    assert cp.mean.shape == (61, 3) and cp.components.shape[0] == 183
    assert len(cp.provenance["cameras"]) == 24
    assert np.allclose(cp.components.T @ cp.components, np.eye(cp.size), atol=1e-6)
    assert dp.mean.shape == (61,) and abs(dp.mean.mean() - 1) < 1e-6


@needs_data
def test_prior_excludes_held_out_camera():
    cams = {n: datasets.load_camera(n) for n in datasets.camera_names()}
    held = "Canon_20D"
    full = build_camera_prior(list(cams.values()))
    loo_prior = build_camera_prior([c for n, c in cams.items() if n != held])
    assert loo_prior.size == full.size - 1
    assert not np.allclose(loo_prior.mean, full.mean)
