"""Derive the Gaussian mixture of measured daylight used by the diagnosis (``core/illumon/data/daylight_mixture.json``).

Run: ``python tools/build_daylight_mixture.py``. Reads ``../shared/data/daylight/granada_2600.csv`` (Hernández-Andrés,
Romero, Nieves & Lee, "Color and spectral analysis of daylight in southern Europe", JOSA A 18(6), 1325–1335, 2001),
keeps the training half of :func:`illumon.daylight.measured.split_indices` (the first 1300 spectra in file order, a
split by time), projects each unit-mean spectrum on the shipped daylight components (``daylight_prior.csv``: mean and
4 principal components) and fits Gaussian mixtures of the 4 coefficients by expectation-maximisation (k-means++
start, seed 0, a ridge of 1e-6 of the mean variance on every covariance). The number of components is the one with
the lowest BIC on the training half (Schwarz 1978); the held-out half's mean log-likelihood is recorded for each.

Why a mixture: the coefficients of measured skies are far from Gaussian (a long tail to blue skies, a thin warm end,
a curved locus), so one Gaussian, symmetric about the mean, gives warm lamp light the probability of blue sky. On the
held-out half the mixture's log-likelihood per spectrum is ~1.7 nats above the single Gaussian's.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from illumon.daylight.measured import split_indices
from illumon.priors import default_daylight_prior
from illumon.simulation import datasets
from numpy.typing import NDArray

OUT = Path(__file__).resolve().parents[1] / "core" / "illumon" / "data" / "daylight_mixture.json"
COMPONENTS = (1, 2, 3, 4, 5, 6, 8)


def _log_densities(x: NDArray[np.float64], w, mu, cov) -> NDArray[np.float64]:
    out = np.zeros((x.shape[0], len(w)))
    for j in range(len(w)):
        d = x - mu[j]
        ci = np.linalg.inv(cov[j])
        out[:, j] = (np.log(w[j]) - 0.5 * np.einsum("ni,ij,nj->n", d, ci, d) - 0.5 * np.linalg.slogdet(cov[j])[1]
                     - 0.5 * x.shape[1] * np.log(2 * np.pi))
    return out


def _loglik(x, w, mu, cov) -> float:
    lp = _log_densities(x, w, mu, cov)
    m = lp.max(1, keepdims=True)
    return float((np.log(np.exp(lp - m).sum(1)) + m[:, 0]).sum())


def fit_mixture(x: NDArray[np.float64], k: int, seed: int = 0, iters: int = 500, ridge: float = 1e-6):
    """Gaussian mixture by EM from a k-means++ start: weights (k,), means (k × d), covariances (k × d × d)."""
    rng = np.random.default_rng(seed)
    n, d = x.shape
    mu = x[rng.choice(n, 1)]
    for _ in range(k - 1):
        d2 = ((x[:, None] - mu[None]) ** 2).sum(-1).min(1)
        mu = np.vstack([mu, x[rng.choice(n, p=d2 / d2.sum())]])
    reg = ridge * np.trace(np.cov(x.T)) / d * np.eye(d)
    cov = np.array([np.cov(x.T) for _ in range(k)])
    w = np.full(k, 1.0 / k)
    last = -np.inf
    for _ in range(iters):
        lp = _log_densities(x, w, mu, cov)
        m = lp.max(1, keepdims=True)
        r = np.exp(lp - m)
        ll = float((np.log(r.sum(1)) + m[:, 0]).sum())
        r /= r.sum(1, keepdims=True)
        nk = r.sum(0)
        w = nk / n
        mu = (r.T @ x) / nk[:, None]
        for j in range(k):
            dd = x - mu[j]
            cov[j] = (r[:, j, None] * dd).T @ dd / nk[j] + reg
        if ll - last < 1e-9 * abs(ll):
            break
        last = ll
    return w, mu, cov


def main() -> None:
    dp = default_daylight_prior()
    ids, spectra = datasets.load_granada_daylight()
    train, test = split_indices(len(ids), "time")

    def coefs(idx):
        s = spectra[idx] / spectra[idx].mean(1, keepdims=True)
        return np.linalg.lstsq(dp.components, (s - dp.mean).T, rcond=None)[0].T

    x, xt = coefs(train), coefs(test)
    table, best = [], None
    for k in COMPONENTS:
        w, mu, cov = fit_mixture(x, k)
        ll = _loglik(x, w, mu, cov)
        n_par = k * (4 + 10) + k - 1
        bic = -2 * ll + n_par * np.log(x.shape[0])
        held = _loglik(xt, w, mu, cov) / xt.shape[0]
        table.append({"components": k, "bic_training": round(bic, 1), "heldout_loglik_per_spectrum": round(held, 3)})
        print(f"k={k}: BIC {bic:.1f}, held-out log-likelihood per spectrum {held:.3f}")
        if best is None or bic < best[0]:
            best = (bic, k, w, mu, cov)
    _, k, w, mu, cov = best
    out = {
        "version": 1,
        "n_components": k,
        "weights": w.tolist(),
        "means": mu.tolist(),
        "covariances": cov.tolist(),
        "coefficients_of": "daylight_prior.csv (mean + 4 principal components, unit-mean spectra 400-700 nm)",
        "selection": table,
        "provenance": {
            "source": "Hernández-Andrés J, Romero J, Nieves JL, Lee RL Jr, JOSA A 18(6):1325-1335 (2001); "
                      "shared/data/daylight/granada_2600.csv",
            "training": f"time split, first {train.size} spectra ({ids[train[0]]}..{ids[train[-1]]})",
            "builder": "tools/build_daylight_mixture.py (EM, k-means++ start, seed 0; k by BIC on the training half)",
            "licence_note": "derived from published measurements; research use, cite the source paper",
        },
    }
    OUT.write_text(json.dumps(out, indent=1) + "\n")
    print(f"k = {k} written to {OUT}")


if __name__ == "__main__":
    main()
