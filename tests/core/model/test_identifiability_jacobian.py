"""The identifiability check's data-only Jacobian (issue 29): stepping one parameter of every frame (of every patch)
per evaluation gives the Jacobian of one evaluation per column, bit for bit (each frame's and patch's rows are computed
on their own), so the condition and singular values are unchanged."""

from __future__ import annotations

import importlib

import numpy as np
from illumon.daylight import CIEDaylight
from illumon.priors import reflectance_basis

ident = importlib.import_module("illumon.model.identifiability")  # the package's attribute is the function


def _reference_jacobian(css, dm, rb, theta, coef, w2, max_frames=40):
    """The Jacobian as the check computed it before: one forward difference per column (the same prediction)."""
    sel = ident.spread_subsample(theta[:, 0], max_frames)
    pred, x0, steps = ident._whitened_prediction(css, dm, rb, theta[sel], coef, w2[sel])
    r0 = pred(x0)
    jac = np.empty((r0.size, x0.size))
    for j in range(x0.size):
        h = 1e-4 * steps[j]
        xp = x0.copy()
        xp[j] += h
        jac[:, j] = (pred(xp) - r0) / h * steps[j]
    return jac


def test_batched_differences_equal_one_column_at_a_time(monkeypatch):
    rng = np.random.default_rng(3)
    wl = np.arange(400, 701, 5)
    css = np.column_stack([np.exp(-0.5 * ((wl - c) / 30) ** 2) for c in (600, 540, 460)])
    dm, rb = CIEDaylight(), reflectance_basis()
    n, p = 60, 7
    theta = np.column_stack([rng.uniform(80, 250, n), rng.normal(0, 0.003, n), rng.normal(0, 0.3, n)])
    coef = rb.prior_mean + rng.normal(0, 0.3, (p, rb.size))
    w2 = rng.uniform(0.5, 2.0, (n, p, 3)) * 1e4
    w2[rng.random((n, p)) < 0.1] = 0.0  # missing patches carry no weight
    y = np.ones((n, p, 3))
    seen = []
    real_svd = np.linalg.svd
    monkeypatch.setattr(np.linalg, "svd", lambda a, **kw: (seen.append(a.copy()), real_svd(a, **kw))[1])
    out = ident.identifiability(y, w2[..., 0] > 0, css, dm, rb, theta, coef, w2, 1e6 / (1e6 / theta[:, 0]))
    ref = _reference_jacobian(css, dm, rb, theta, coef, w2)
    assert len(seen) == 1 and np.array_equal(seen[0], ref)
    assert out["condition_frames"] == 40 and np.isfinite(out["condition"])
