"""Gray-world over a history as evidence of the light (:func:`illumon.priors.scene_average.scene_average_evidence`)."""

from __future__ import annotations

import math

import numpy as np
from illumon.priors import scene_average as sa


def _per_frame(y: np.ndarray, present: np.ndarray) -> sa.SceneAverage:
    """The frame-by-frame computation :func:`~illumon.priors.scene_average.scene_average_evidence` replaced."""
    logs, spreads, counts = [], [], []
    for yf, pf in zip(y, present, strict=True):
        v = yf[pf]
        if len(v) < 2:
            continue
        m = v.mean(axis=0)
        if not np.all(m > 0):
            continue
        logs.append(np.log(m[[0, 2]] / m[1]))
        eps = sa._CHROMA_FLOOR * float(m.mean())
        lc = np.log((np.clip(v[:, [0, 2]], 0, None) + eps) / (np.clip(v[:, 1:2], 0, None) + eps))
        spreads.append(float(np.sqrt(np.mean(np.var(lc, axis=0)))))
        counts.append(len(v))
    if not logs:
        return sa.SceneAverage(np.zeros(2), math.inf, math.inf, 0.0)
    spread, n = float(np.median(spreads)), float(np.mean(counts))
    return sa.SceneAverage(np.mean(logs, axis=0), math.sqrt(sa.SCENE_GREY_SD**2 + spread**2 / n), spread, n)


def test_equals_frame_by_frame_bit_for_bit() -> None:
    """Every frame count, patch count, missing pattern, dark and negative value: the same four numbers, bit for
    bit (issue 29)."""
    rng = np.random.default_rng(1)
    for trial in range(300):
        f, p = int(rng.integers(1, 60)), int(rng.integers(1, 20))
        y = np.exp(rng.normal(-1, 1, (f, p, 3))) * rng.choice([1, 1, 1, 0, -0.01], (f, p, 3))
        if trial % 3 == 0:
            y = rng.uniform(0, 1, (f, p, 3))
        present = rng.random((f, p)) < rng.uniform(0.1, 1)
        y[~present] = np.nan
        got, want = sa.scene_average_evidence(y, present), _per_frame(y, present)
        np.testing.assert_array_equal(got.mean, want.mean)
        assert (got.sd, got.spread, got.patches) == (want.sd, want.spread, want.patches) or (
            math.isinf(got.sd) and math.isinf(want.sd)), trial
