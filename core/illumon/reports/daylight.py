"""``illumon report daylight``: how well the product's daylight models fit measured daylight, why they fail, and what
the measured-daylight model (:mod:`illumon.daylight.measured`) gains for the estimator.

Models compared on every measured spectrum (unit-mean scale, best scale per fit):

* ``cie_cct`` — CIE D at the spectrum's own CCT, on the daylight locus (CIE 015:2018 §4.1.2);
* ``cie_xy`` — CIE D at the spectrum's own chromaticity (off-locus allowed);
* ``cie_free`` — free least-squares weights on S0, S1, S2;
* ``theta`` — Marguier & Süsstrunk's one-parameter θ curve (CIC 2007), best θ;
* ``measured_xy`` / ``measured_free`` — the measured model at the own chromaticity / free fit (held-out spectra only).

Errors: relative RMSE (RMSE / mean level, best scale) and the goodness-of-fit coefficient GFC (Romero, García-Beltrán &
Hernández-Andrés, JOSA A 14, 1997; GFC ≥ 0.999 "colorimetrically accurate", ≥ 0.9999 "good spectral fit"
after Hernández-Andrés et al., JOSA A 18, 2001). Gain: the camera-white error each daylight model leaves at the true
chromaticity (all held-out spectra × all cameras), and full joint retrieval on simulated fixed-camera histories lit
by held-out spectra (:func:`illumon.retrieval.joint.illuminant_retrieval_illumon`).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from .._blas import single_blas_thread
from ..daylight import (
    CIE_D_BASIS,
    cct_duv_from_xy,
    daylight_locus_duv,
    daylight_spectrum,
    theta_curve,
    xy_from_cct_duv,
    xy_from_spectrum,
)
from ..daylight.measured import (
    MeasuredDaylightData,
    fit_measured_daylight,
    free_fit,
    split_indices,
    unit_mean,
)
from ..spectra import GRID, WAVELENGTHS, SpectralInputError, read_spectral_csv, resample_columns
from . import render
from .detect import detect_band, detect_tint
from .gain import daylight_gain
from .metrics import gfc, q, rel_rmse, scaled

__all__ = ["daylight_report", "load_measured_spectra", "fit_daylight_models", "sky_class"]

BANDS = ((400, 450), (450, 500), (500, 550), (550, 600), (600, 650), (650, 700))
CCT_BINS = (0, 4500, 5500, 6500, 8000, 11000, 1e9)
FEATURES = {  # known spectral features of global irradiance within 400–700 nm (nm: cause)
    431: "Fraunhofer G (Fe/CH) line",
    486: "Fraunhofer F (Hβ) line",
    518: "Fraunhofer b (Mg) lines",
    589: "Na D lines / O3 Chappuis band",
    600: "O3 Chappuis band maximum",
    628: "O2 γ band",
    651: "H2O band",
    656: "Fraunhofer C (Hα) line",
    687: "O2 B band",
    695: "H2O band",
}
MIN_SPECTRA = 10


def load_measured_spectra(path: str | Path) -> tuple[list[str], NDArray[np.float64], dict]:
    """Read ``wavelength_nm,<id>…`` spectra onto the grid (N × 61, unit mean); raises :class:`SpectralInputError`.

    Spectra with a non-positive value within 400–700 nm cannot be daylight and are dropped (counted in the info).
    """
    wl, values, names = read_spectral_csv(path)
    if values.shape[1] == 0:
        raise SpectralInputError(f"{path}: no spectra (expected columns wavelength_nm,<id>,…)")
    try:
        grid = resample_columns(wl, values, GRID).T
    except SpectralInputError as exc:
        raise SpectralInputError(f"{path}: {exc}") from None
    ok = np.all(grid > 0, axis=1)
    if ok.sum() < MIN_SPECTRA:
        raise SpectralInputError(
            f"{path}: {int(ok.sum())} usable spectra (positive over 400–700 nm); the report needs ≥ {MIN_SPECTRA}"
        )
    info = {"n_file": int(values.shape[1]), "n_dropped_nonpositive": int((~ok).sum()),
            "file_range_nm": [float(wl[0]), float(wl[-1])]}
    return [n for n, k in zip(names, ok, strict=True) if k], unit_mean(grid[ok]), info


def _theta_fit(e: NDArray[np.float64]) -> NDArray[np.float64]:
    tc = theta_curve()
    lo, hi = tc.theta_range
    pad = 0.5 * (hi - lo)
    th = np.linspace(lo - pad, hi + pad, 600)
    t = tc.spectrum(th)  # T × 61
    tn = t / np.linalg.norm(t, axis=1, keepdims=True)
    proj = e @ tn.T  # N × T
    best = np.argmax(proj, axis=1)  # max projection = min residual after scaling
    return t[best]


def fit_daylight_models(
    e: NDArray[np.float64], data: MeasuredDaylightData | None = None
) -> dict[str, NDArray[np.float64]]:
    """Best-scaled fits (N × 61) of unit-mean spectra ``e`` by each model (see module docstring)."""
    xy = xy_from_spectrum(e)
    cct, _ = cct_duv_from_xy(xy)
    fits = {
        "cie_cct": daylight_spectrum(xy_from_cct_duv(cct, daylight_locus_duv(cct))),
        "cie_xy": daylight_spectrum(xy),
        "cie_free": free_fit(CIE_D_BASIS, e),
        "theta": _theta_fit(e),
    }
    if data is not None:
        fits["measured_xy"] = data.predict(xy)
        fits["measured_free"] = free_fit(data.basis, e)
    return {k: scaled(v, e) for k, v in fits.items()}


def sky_class(cct: NDArray[np.float64], delta: NDArray[np.float64]) -> NDArray[np.str_]:
    """Sky state from the spectrum's shape (its CCT and offset δ from the CIE daylight locus).

    Global irradiance with the sun in view is dominated by the direct beam: 5000–6000 K and *below* the locus
    (δ < 0); with the sun low the beam's long path removes blue (< 4500 K). Overcast light is diffused by clouds,
    which scatter almost neutrally: 6000–8000 K near the locus. Light from blue sky alone (sun hidden by cloud or
    terrain) is Rayleigh-scattered, > 8000 K and *above* the locus (Hernández-Andrés et al. 2001, §4).
    """
    out = np.full(cct.shape, "overcast / mixed", dtype=object)
    out[(cct < 6200) & (delta < 0)] = "clear, sun in view"
    out[cct >= 8000] = "blue sky, sun hidden"
    out[cct < 4500] = "low sun"
    return out.astype(str)


def _nearest_feature(nm: float) -> str:
    k = min(FEATURES, key=lambda f: abs(f - nm))
    return f"{FEATURES[k]} ({k} nm)" if abs(k - nm) <= 12 else "no catalogued feature"


def _model_errors(e: NDArray[np.float64], cct: NDArray[np.float64], delta: NDArray[np.float64],
                  sky: NDArray[np.str_]) -> tuple[dict, dict, dict, dict, list, list, list]:
    """Step 1: every spectrum fitted with the product's models; errors overall, by CCT, band and sky class."""
    fits = fit_daylight_models(e)
    err = {k: {"rmse": rel_rmse(v, e), "gfc": gfc(v, e)} for k, v in fits.items()}
    resid = {k: (v - e) / e for k, v in fits.items()}
    models_summary = {
        k: {
            "median_rmse": q(v["rmse"]),
            "p95_rmse": q(v["rmse"], 95),
            "median_gfc": q(v["gfc"]),
            "frac_gfc_999": float(np.mean(v["gfc"] >= 0.999)),
            "frac_gfc_9999": float(np.mean(v["gfc"] >= 0.9999)),
        }
        for k, v in err.items()
    }
    by_cct = []
    for lo, hi in zip(CCT_BINS[:-1], CCT_BINS[1:], strict=True):
        s = (cct >= lo) & (cct < hi)
        if s.any():
            by_cct.append({
                "cct_from": lo, "cct_to": hi if hi < 1e8 else None, "n": int(s.sum()),
                "median_delta_duv": q(delta[s]),
                **{f"median_rmse_{k}": q(err[k]["rmse"][s]) for k in err},
                **{f"frac_gfc_999_{k}": float(np.mean(err[k]["gfc"][s] >= 0.999)) for k in err},
            })
    by_band = []
    for lo, hi in BANDS:
        s = (WAVELENGTHS >= lo) & (WAVELENGTHS < hi + (hi == 700))
        by_band.append({"band": f"{lo}-{hi}", **{k: float(np.sqrt(np.mean(resid[k][:, s] ** 2))) for k in resid}})
    by_sky = []
    for c in sorted(set(sky)):
        s = sky == c
        by_sky.append({
            "sky": c, "n": int(s.sum()), "median_cct": q(cct[s]), "median_delta_duv": q(delta[s]),
            **{f"median_rmse_{k}": q(err[k]["rmse"][s]) for k in err},
            **{f"frac_gfc_999_{k}": float(np.mean(err[k]["gfc"][s] >= 0.999)) for k in err},
        })

    return fits, err, resid, models_summary, by_cct, by_band, by_sky


def _cause(err: dict, resid: dict, cct: NDArray[np.float64], delta: NDArray[np.float64], by_band: list,
           models_summary: dict) -> tuple[dict, NDArray[np.float64]]:
    """Step 2: which spectra fail under CIE D at their own chromaticity, where in the spectrum, and why."""
    fail = err["cie_xy"]["gfc"] < 0.999
    rms_wl = np.sqrt(np.mean(resid["cie_xy"] ** 2, axis=0))
    rms_fail = np.sqrt(np.mean(resid["cie_xy"][fail] ** 2, axis=0)) if fail.any() else rms_wl
    peak_nm = float(WAVELENGTHS[int(np.argmax(rms_fail))])
    band_rows = sorted(by_band, key=lambda r: -r["cie_xy"])
    corr = {
        "rmse_vs_abs_delta": float(np.corrcoef(np.log(err["cie_xy"]["rmse"]), np.abs(delta))[0, 1]),
        "rmse_vs_mired": float(np.corrcoef(np.log(err["cie_xy"]["rmse"]), 1e6 / cct)[0, 1]),
    }
    cause = {
        "n_fail_cie_xy": int(fail.sum()),
        "frac_fail_cie_xy": float(fail.mean()),
        "median_cct_fail": q(cct[fail]) if fail.any() else None,
        "median_cct_pass": q(cct[~fail]) if (~fail).any() else None,
        "frac_fail_above_8000K": float(np.mean(fail[cct >= 8000])) if np.any(cct >= 8000) else None,
        "frac_fail_below_6200K": float(np.mean(fail[cct < 6200])) if np.any(cct < 6200) else None,
        "frac_off_locus_003": float(np.mean(np.abs(delta) > 0.003)),
        "median_abs_delta_fail": q(np.abs(delta[fail])) if fail.any() else None,
        "median_abs_delta_pass": q(np.abs(delta[~fail])) if (~fail).any() else None,
        "worst_band": band_rows[0]["band"],
        "peak_residual_nm_fail": peak_nm,
        "peak_feature": _nearest_feature(peak_nm),
        "correlations": corr,
        "cie_cct_vs_cie_xy_median_rmse": [models_summary["cie_cct"]["median_rmse"],
                                          models_summary["cie_xy"]["median_rmse"]],
    }

    return cause, rms_fail


def _extension(e: NDArray[np.float64], train: NDArray[np.int64], test: NDArray[np.int64], source: str, split: str,
               seed: int) -> tuple[MeasuredDaylightData, dict, dict, list]:
    """Step 3: the measured basis on the training split (k by cross-validation inside it), held-out errors."""
    data = fit_measured_daylight(e[train], provenance={"source": source, "split": split, "seed": seed})
    e_test = e[test]
    fits_test = fit_daylight_models(e_test, data)
    held = {k: {"median_rmse": q(rel_rmse(v, e_test)), "median_gfc": q(gfc(v, e_test)),
                "frac_gfc_999": float(np.mean(gfc(v, e_test) >= 0.999)),
                "frac_gfc_9999": float(np.mean(gfc(v, e_test) >= 0.9999))}
            for k, v in fits_test.items()}
    mu_t = e[train].mean(0)
    vt = np.linalg.svd(e[train] - mu_t, full_matrices=False)[2]
    k_curve = [q(rel_rmse(free_fit(np.column_stack([mu_t, vt[:k].T]), e_test), e_test)) for k in range(1, 11)]
    extension = {
        "n_components": data.k, "cv_errors": data.cv_errors.tolist(), "held_out_median_rmse_by_k": k_curve,
        "delta_prior": {"coef": data.delta_coef.tolist(), "sd": data.delta_sd},
        "n_train": int(train.size), "n_held_out": int(test.size),
    }

    return data, held, extension, k_curve


def _detection(e: NDArray[np.float64], ids: list[str]) -> tuple[dict, dict]:
    """Hidden-distortion search (physics-based residual analysis against the shipped measured model)."""
    band = detect_band(e)
    tint = detect_tint(e)
    detection = {
        "band": {k: band[k] for k in ("found", "centre_nm", "fwhm_nm", "depth_median")}
        | {"n_affected": len(band["affected"]), "affected_ids": [ids[i] for i in band["affected"]],
           "feature": _nearest_feature(band["centre_nm"]) if band["found"] else None},
        "tint": {k: tint[k] for k in ("found", "shift_duv", "separation")}
        | {"n_affected": len(tint["affected"]), "affected_ids": [ids[i] for i in tint["affected"]]},
    }

    return detection, band


def _figures(cct: NDArray[np.float64], delta: NDArray[np.float64], sky: NDArray[np.str_], err: dict, resid: dict,
             rms_fail: NDArray[np.float64], data: MeasuredDaylightData, k_curve: list, band: dict, gain: dict) -> dict:
    """The numbers behind every plot (``figures.json``)."""
    return {
        "error_vs_cct": {"cct": cct.tolist(), **{f"gfc_{k}": err[k]["gfc"].tolist() for k in err},
                         **{f"rmse_{k}": err[k]["rmse"].tolist() for k in err}},
        "delta_vs_cct": {"cct": cct.tolist(), "delta_duv": delta.tolist(), "sky": sky.tolist(),
                         "prior_mired": np.linspace(*data.mired_range, 20).tolist(),
                         "prior_delta": data.delta_mean(np.linspace(*data.mired_range, 20)).tolist()},
        "residual_by_wavelength": {"wavelength_nm": WAVELENGTHS.tolist(),
                                   **{k: np.sqrt(np.mean(v**2, 0)).tolist() for k, v in resid.items()},
                                   "cie_xy_failing": rms_fail.tolist()},
        "held_out_error_by_k": {"k": list(range(1, 11)), "median_rmse": k_curve,
                                "cv_error": data.cv_errors[:10].tolist()},
        "band_scan": {"centre_nm": band["centres"], "evidence": band["profile"]},
        "gain": {k: v for k, v in gain.items() if k != "retrieval"}
        | ({"retrieval_per_history": gain["retrieval"]["histories"]} if "retrieval" in gain else {}),
    }


@single_blas_thread
def daylight_report(
    spectra_csv_path: str | Path,
    out_dir: str | Path,
    *,
    split: str = "time",
    seed: int = 0,
    n_histories: int = 12,
    n_frames: int = 30,
    n_patches: int = 10,
    time_budget_s: float = 30.0,
    simulate: bool = True,
    solver_kwargs: dict | None = None,
    plots: bool = True,
) -> dict:
    """Write the daylight report for a measured spectra file and return its numbers.

    Parameters
    ----------
    spectra_csv_path
        ``wavelength_nm,<id>…`` CSV covering 400–700 nm (any sampling; resampled to the grid).
    out_dir
        Output folder (created): ``report.md``, ``figures.json``, ``summary.json`` and PNG plots.
    split, seed
        Training / held-out split of the file (:func:`illumon.daylight.measured.split_indices`): ``"time"`` (file
        order, first half trains) or ``"random"`` halves.
    n_histories, n_frames, n_patches
        Simulated fixed-camera histories for the gain: count, frames each (held-out spectra), static patches each
        (random measured reflectances).
    time_budget_s
        Wall-clock budget of the simulated retrievals; histories beyond it are skipped (the report says how many ran).
    simulate
        Run the simulated retrievals (needs the measured cameras and reflectances of :mod:`illumon.simulation.datasets`).
    solver_kwargs
        Extra keyword arguments for :func:`~illumon.retrieval.joint.illuminant_retrieval_illumon` (unknown ones are
        ignored).
    plots
        Draw the PNG plots (matplotlib, Agg).

    Returns
    -------
    dict
        The summary (also written to ``summary.json``).
    """
    t_start = time.perf_counter()
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ValueError(f"cannot create output folder {out}: {exc.strerror or exc}") from None
    ids, e, load_info = load_measured_spectra(spectra_csv_path)
    n = len(ids)
    train, test = split_indices(n, split, seed)
    xy = xy_from_spectrum(e)
    cct, duv = cct_duv_from_xy(xy)
    delta = duv - daylight_locus_duv(cct)
    sky = sky_class(cct, delta)

    fits, err, resid, models_summary, by_cct, by_band, by_sky = _model_errors(e, cct, delta, sky)
    cause, rms_fail = _cause(err, resid, cct, delta, by_band, models_summary)
    data, held, extension, k_curve = _extension(e, train, test, str(spectra_csv_path), split, seed)
    gain = daylight_gain(e[test], data, split, seed, simulate=simulate, n_histories=n_histories, n_frames=n_frames,
                         n_patches=n_patches, time_budget_s=time_budget_s, solver_kwargs=solver_kwargs)
    detection, band = _detection(e, ids)
    summary = {
        "input": {"path": str(spectra_csv_path), "n_spectra": n, **load_info,
                  "cct_percentiles_5_50_95": [q(cct, 5), q(cct), q(cct, 95)]},
        "models": models_summary, "by_cct": by_cct, "by_band": by_band, "by_sky": by_sky, "cause": cause,
        "held_out": held, "extension": extension, "gain": gain, "detection": detection,
    }
    figures = _figures(cct, delta, sky, err, resid, rms_fail, data, k_curve, band, gain)
    (out / "figures.json").write_text(json.dumps(figures))
    summary["seconds"] = time.perf_counter() - t_start
    if plots:
        summary["plots"] = render.plots(out, figures, fits, e, err)
    (out / "summary.json").write_text(json.dumps(summary, indent=1, default=float))
    (out / "report.md").write_text(render.markdown(summary))
    return summary
