"""Data splits (issue 30): what a benchmark calls held out or scores on is disjoint from what development used, and
no prior a benchmark scores with contains a score camera."""

from __future__ import annotations

import numpy as np
import pytest
import rawsim
from illumon.simulation import datasets, effects


def test_rawsim_splits_are_disjoint():
    assert not set(rawsim.DEV_CAMERAS) & set(rawsim.SCORE_CAMERAS)
    assert not {rawsim.manufacturer(c) for c in rawsim.DEV_CAMERAS} & {rawsim.manufacturer(c) for c in rawsim.SCORE_CAMERAS}
    assert not set(rawsim.DEV_REFLECTANCE_SETS) & set(rawsim.SCORE_REFLECTANCE_SETS)
    dev = set(range(2600)[rawsim.DEV_DAYLIGHT])
    score = set(range(2600)[rawsim.SCORE_DAYLIGHT])
    assert dev and score and not dev & score


def test_diagnosis_camera_splits_are_disjoint():
    assert not set(effects.DEV_CAMERAS) & set(effects.TEST_CAMERAS)
    # the diagnosis benchmark scores on rawsim's score cameras: no development camera of its margins among them
    assert not set(rawsim.DEV_CAMERAS) & set(rawsim.SCORE_CAMERAS)


def test_peers_scores_held_out_cameras_surfaces_and_daylight(shared_data):
    peers = pytest.importorskip("peers")
    assert set(peers.SCORE_CAMERAS) <= set(rawsim.SCORE_CAMERAS)
    assert not set(peers.SCORE_CAMERAS) & set(rawsim.DEV_CAMERAS)
    assert peers.SCORE_DAYLIGHT == rawsim.SCORE_DAYLIGHT
    # the unmeasured-camera rows' prior: the development cameras only (no score camera in a prior)
    np.testing.assert_allclose(peers.dev_camera_prior_mean(), _prior_mean(rawsim.DEV_CAMERAS))
    # score surfaces: none of them is a spectrum of the sets the reflectance basis was built from
    from illumon.priors import unseen_reflectances

    _, unseen = unseen_reflectances()
    score = unseen[: peers.SCORE_SURFACES]
    basis_sets = np.concatenate([datasets.load_reflectance_set(n)[1] for n in datasets.REFLECTANCE_SETS])
    dist = np.min(np.abs(score[:, None, :] - basis_sets[None]).max(-1), axis=1)
    assert dist.min() > 1e-3
    # …while the 15 after them are (why they are left out)
    later = unseen[peers.SCORE_SURFACES :]
    assert np.min(np.abs(later[:, None, :] - basis_sets[None]).max(-1), axis=1).max() < 1e-3


def _prior_mean(cameras) -> np.ndarray:
    from illumon.priors import max_normalise

    return np.mean([max_normalise(datasets.load_camera(c)) for c in cameras], axis=0)
