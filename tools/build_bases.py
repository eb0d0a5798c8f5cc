"""Derive the reflectance basis shipped in ``core/illumon/data`` from the measured sets in ``../shared/data``.

Run: ``python tools/build_bases.py``. Writes ``reflectance_basis.csv`` (8 components on 400–700 nm / 5 nm) and
``reflectance_prior.json`` (mean and covariance of the sets' coefficients in that basis, and provenance).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from illumon.simulation import datasets
from illumon.spectra import WAVELENGTHS, write_spectral_csv

OUT = Path(__file__).resolve().parents[1] / "core" / "illumon" / "data"
N_COMPONENTS = 8


def main() -> None:
    spectra, counts = [], {}
    for name in datasets.REFLECTANCE_SETS:
        _, r = datasets.load_reflectance_set(name)
        spectra.append(r)
        counts[name] = int(r.shape[0])
    # Each set weighs the same in the basis, so 1269 Munsell chips do not drown the natural surfaces.
    weights = np.concatenate([np.full(r.shape[0], 1.0 / r.shape[0]) for r in spectra])
    data = np.concatenate(spectra)
    w = np.sqrt(weights / weights.sum())[:, None]
    _, s, vt = np.linalg.svd(data * w, full_matrices=False)
    basis = vt[:N_COMPONENTS].T
    # Orient components so that the first is positive and the largest excursion of each is positive.
    for k in range(N_COMPONENTS):
        if basis[np.argmax(np.abs(basis[:, k])), k] < 0:
            basis[:, k] *= -1
    coef = data @ basis
    recon = coef @ basis.T
    rmse = float(np.sqrt(np.mean((recon - data) ** 2)))
    energy = float((s[:N_COMPONENTS] ** 2).sum() / (s**2).sum())
    mean = (coef * weights[:, None]).sum(0) / weights.sum()
    cov = ((coef - mean).T * weights) @ (coef - mean) / weights.sum()
    write_spectral_csv(
        OUT / "reflectance_basis.csv",
        WAVELENGTHS,
        {f"b{k + 1}": basis[:, k] for k in range(N_COMPONENTS)},
        comments=[
            "illumon reflectance basis: first 8 right singular vectors (uncentred, equal weight per set)",
            "built by tools/build_bases.py from shared/data/reflectances: " + ", ".join(f"{k} ({v})" for k, v in counts.items()),
            "source data licences: UEF/Joensuu sets non-commercial use only; Vrhel/SFU sets no stated licence",
        ],
    )
    prior = {
        "version": 1,
        "sets": counts,
        "n_components": N_COMPONENTS,
        "energy_captured": energy,
        "rmse_reconstruction": rmse,
        "coefficient_mean": mean.tolist(),
        "coefficient_covariance": cov.tolist(),
    }
    (OUT / "reflectance_prior.json").write_text(json.dumps(prior, indent=1))
    print(f"basis energy {energy:.5f}, rmse {rmse:.4f}")


if __name__ == "__main__":
    main()
