"""Derive the data that :mod:`illumon.sensitivity` ships in ``core/illumon/data`` from ``../shared/data``.

Run: ``python tools/build_sensitivity_priors.py``. Writes

* ``camera_prior.csv`` / ``camera_prior.json`` — joint PCA (mean, components, variances) of the 24 measured
cameras'
  max-normalised sensitivities, and the per-channel Jiang et al. (2013) eigenvectors
  (``colour.recovery.PCA_Jiang2013``);
* ``rendered_camera_prior.csv`` / ``.json`` — the same of the 24 cameras each carried to sRGB primaries with a D65
  daylight preset (``illumon.camera.primaries.to_srgb_primaries``): the prior of a camera whose colour matrix is on;
* ``daylight_prior.csv`` / ``daylight_prior.json`` — PCA of the 2600 Granada daylight spectra (unit mean on
  400–700 nm) with the Gaussian of their coefficients;
* ``fluorophores.csv`` — excitation and emission spectra (400–700 nm, 5 nm, peak-normalised) of 12
fluorophores
  from the McNamara & Boswell compilation, chosen so that their emission peaks spread over 430–670 nm and a
  good
  share of their excitation lies in the visible, where daylight is strong. Used to simulate Han et al.'s
  chart.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
from illumon.camera.primaries import to_srgb_primaries
from illumon.priors import build_camera_prior, build_daylight_prior
from illumon.simulation import datasets
from illumon.spectra import WAVELENGTHS, write_spectral_csv

OUT = Path(__file__).resolve().parents[1] / "core" / "illumon" / "data"
CAMERA_LICENCE = (
    "derived from camera sensitivities licensed CC BY-NC-SA 4.0 (Jiang, Liu, Gu & Süsstrunk 2013 database, "
    "RIT; Glenn Butcher 2020); this derived file is CC BY-NC-SA 4.0 as well"
)
N_DAYLIGHT = 4
FLUOROPHORE_TARGETS = tuple(range(430, 671, 12))


def build_cameras() -> None:
    names = datasets.camera_names()
    cams = [datasets.load_camera(n) for n in names]
    write_camera_prior("camera_prior", cams, names, "illumon camera-sensitivity prior: joint PCA of max-normalised "
                       "(r,g,b) curves, measured cameras", "shared/data/cameras")
    write_camera_prior("rendered_camera_prior", [to_srgb_primaries(c) for c in cams], names,
                       "illumon rendered-camera prior: joint PCA of max-normalised (r,g,b) curves, measured cameras "
                       "each carried to sRGB primaries with a D65 preset (illumon.camera.primaries.to_srgb_primaries)",
                       "shared/data/cameras through illumon.camera.primaries.to_srgb_primaries")


def write_camera_prior(stem: str, cams: list[np.ndarray], names: list[str], title: str, built_from: str) -> None:
    """``<stem>.csv`` / ``<stem>.json``: the camera prior of ``cams`` (as ``illumon.priors`` loads it)."""
    prior = build_camera_prior(cams)
    cols: dict[str, np.ndarray] = {f"mean_{c}": prior.mean[:, i] for i, c in enumerate("rgb")}
    n = WAVELENGTHS.size
    for j in range(prior.size):
        for i, c in enumerate("rgb"):
            cols[f"pc{j + 1}_{c}"] = prior.components[i * n : (i + 1) * n, j]
    for j in range(prior.channel_bases.shape[2]):
        for i, c in enumerate("rgb"):
            cols[f"jiang{j + 1}_{c}"] = prior.channel_bases[i, :, j]
    write_spectral_csv(
        OUT / f"{stem}.csv",
        WAVELENGTHS,
        cols,
        comments=[
            title,
            f"built by tools/build_sensitivity_priors.py from {built_from}: " + ", ".join(names),
            "licence: " + CAMERA_LICENCE,
        ],
    )
    meta = {
        "version": 1,
        "cameras": names,
        "n_components": prior.size,
        "variances": prior.variances.tolist(),
        "residual_variance": prior.residual_variance,
        "n_channel_basis": int(prior.channel_bases.shape[2]),
        "source": "shared/data/cameras (Jiang et al. WACV 2013 database, 20; Glenn Butcher 2020, 4)"
                  + ("" if stem == "camera_prior" else ", through illumon.camera.primaries.to_srgb_primaries"),
        "licence": CAMERA_LICENCE,
    }
    (OUT / f"{stem}.json").write_text(json.dumps(meta, indent=1))


def build_daylight() -> None:
    ids, spectra = datasets.load_granada_daylight()
    prior = build_daylight_prior(spectra, N_DAYLIGHT)
    unit = spectra / spectra.mean(1, keepdims=True)
    recon = prior.mean + ((unit - prior.mean) @ prior.components) @ prior.components.T
    rmse = float(np.sqrt(np.mean((recon - unit) ** 2)))
    write_spectral_csv(
        OUT / "daylight_prior.csv",
        WAVELENGTHS,
        {"mean": prior.mean, **{f"pc{j + 1}": prior.components[:, j] for j in range(prior.size)}},
        comments=[
            "illumon daylight prior: mean and principal components of 2600 Granada spectra (unit mean)",
            "Hernandez-Andres, Romero, Nieves & Lee, JOSA A 18(6) 2001; tools/build_sensitivity_priors.py",
        ],
    )
    meta = {
        "version": 1,
        "spectra": len(ids),
        "n_components": prior.size,
        "rmse_reconstruction": rmse,
        "coefficient_mean": prior.coefficient_mean.tolist(),
        "coefficient_covariance": prior.coefficient_covariance.tolist(),
        "source": "shared/data/daylight/granada_2600.csv (Hernández-Andrés et al. 2001)",
        "licence": "derived from published measurements; redistributed for research with attribution",
    }
    (OUT / "daylight_prior.json").write_text(json.dumps(meta, indent=1))


def build_fluorophores() -> None:
    path = datasets.shared_data_dir() / "fluorophores" / "mcnamara_boswell.csv"
    with open(path, newline="") as fh:
        rows = list(csv.reader(fh))
    wl = np.asarray([float(v) for v in rows[0][3:]])
    keep = (wl >= 400) & (wl <= 700)
    spectra: dict[tuple[str, str], dict[str, np.ndarray]] = {}
    for row in rows[1:]:
        values = np.asarray([float(v) if v.strip() else 0.0 for v in row[3:]])
        spectra.setdefault((row[0].strip(), row[1].strip()), {})[row[2].strip()] = values
    candidates = []
    for key, d in spectra.items():
        if "excitation" not in d or "emission" not in d:
            continue
        ex, em = d["excitation"], d["emission"]
        if ex.sum() <= 0 or em.sum() <= 0:
            continue
        vis_ex = ex[keep].sum() / ex.sum()
        vis_em = em[keep].sum() / em.sum()
        peak = wl[np.argmax(em)]
        if vis_ex < 0.5 or vis_em < 0.9:
            continue
        candidates.append((key, peak, vis_ex, ex[keep], em[keep]))
    chosen, used = [], set()
    for target in FLUOROPHORE_TARGETS:
        best = min(
            (c for c in candidates if c[0][0] not in used),
            key=lambda c: (abs(c[1] - target), -c[2]),
        )
        used.add(best[0][0])
        chosen.append(best)
    cols: dict[str, np.ndarray] = {}
    notes = []
    for i, (key, peak, _vis, ex, em) in enumerate(chosen, start=1):
        cols[f"ex{i:02d}"] = ex / ex.max()
        cols[f"em{i:02d}"] = em / em.max()
        notes.append(f"f{i:02d}: {key[0]} ({key[1] or 'no solvent given'}), emission peak {peak:g} nm")
    write_spectral_csv(
        OUT / "fluorophores.csv",
        WAVELENGTHS,
        cols,
        comments=[
            "excitation (exNN) and emission (emNN) spectra of 21 fluorophores, 400-700 nm, peak-normalised",
            "from the McNamara & Boswell fluorophore spectra compilation (shared/data/fluorophores)",
            *notes,
        ],
    )


def main() -> None:
    build_cameras()
    build_daylight()
    build_fluorophores()


if __name__ == "__main__":
    main()
