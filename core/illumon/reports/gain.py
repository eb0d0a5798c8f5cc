"""Step 4 of the daylight report: what the measured-daylight model gains where it matters.

Two measures, on the held-out spectra: the camera-white error each daylight model leaves at the true chromaticity
(every held-out spectrum through every measured camera), and full joint retrieval
(:func:`illumon.retrieval.joint.illuminant_retrieval_illumon`) on simulated fixed-camera histories
(:func:`illumon.simulation.simulate_history`) lit by held-out spectra, with each model. Both need the measured cameras
and reflectances of :mod:`illumon.simulation.datasets`; without them the step says it was skipped.
"""

from __future__ import annotations

import inspect
import time

import numpy as np
from numpy.typing import NDArray

from ..camera import angular_error_deg
from ..daylight import daylight_spectrum, xy_from_spectrum
from ..daylight.measured import MeasuredDaylight, MeasuredDaylightData, unit_mean
from ..retrieval.joint import illuminant_retrieval_illumon
from ..simulation import datasets, simulate_history
from .metrics import gfc, q, rel_rmse

__all__ = ["daylight_gain"]


def _camera_white_gain(e: NDArray[np.float64], data: MeasuredDaylightData, cameras: list) -> dict:
    """Angular error of the camera white each model predicts at the true chromaticity (all spectra × cameras)."""
    xy = xy_from_spectrum(e)
    preds = {"cie": daylight_spectrum(xy), "measured": data.predict(xy)}
    out: dict[str, list[float]] = {k: [] for k in preds}
    for c in cameras:
        w = e @ c
        for k, p in preds.items():
            out[k].extend(angular_error_deg(p @ c, w).tolist())
    return {k: np.asarray(v) for k, v in out.items()}


def _simulate_gain(
    e_test: NDArray[np.float64],
    data: MeasuredDaylightData,
    *,
    n_histories: int,
    n_frames: int,
    n_patches: int,
    seed: int,
    time_budget_s: float,
    solver_kwargs: dict | None,
) -> dict:
    """Joint retrieval with each daylight model on simulated histories lit by held-out spectra."""
    rng = np.random.default_rng(seed)
    cams = datasets.camera_names()
    refl = np.concatenate([datasets.load_reflectance_set(n)[1] for n in datasets.REFLECTANCE_SETS])
    accepted = set(inspect.signature(illuminant_retrieval_illumon).parameters)
    kw = {k: v for k, v in (solver_kwargs or {}).items() if k in accepted}
    models = {"cie": "cie", "measured": MeasuredDaylight(data)}
    res: dict[str, dict[str, list[float]]] = {k: {"angular": [], "rmse": [], "gfc": []} for k in models}
    hist = []
    t0 = time.perf_counter()
    for _ in range(n_histories):
        if time.perf_counter() - t0 > time_budget_s:
            break
        cam_name = cams[int(rng.integers(len(cams)))]
        cam = datasets.load_camera(cam_name)
        frames = rng.choice(len(e_test), size=min(n_frames, len(e_test)), replace=False)
        r = refl[rng.choice(len(refl), size=n_patches, replace=False)]
        sim = simulate_history(cam, e_test[frames], r, rng=rng)
        true_white = sim.true_white
        row = {"camera": cam_name, "frames": frames.tolist()}
        for name, model in models.items():
            est = illuminant_retrieval_illumon(sim.observations, cam, daylight=model, **kw)
            ae = angular_error_deg(est.white, true_white)
            truth = unit_mean(e_test[frames])
            res[name]["angular"].extend(ae.tolist())
            res[name]["rmse"].extend(rel_rmse(est.spectra, truth).tolist())
            res[name]["gfc"].extend(gfc(est.spectra, truth).tolist())
            row[f"median_angular_{name}"] = float(np.median(ae))
        hist.append(row)
    return {"per_model": res, "histories": hist, "seconds": time.perf_counter() - t0}


def daylight_gain(e_test: NDArray[np.float64], data: MeasuredDaylightData, split: str, seed: int, *, simulate: bool,
                  n_histories: int, n_frames: int, n_patches: int, time_budget_s: float,
                  solver_kwargs: dict | None) -> dict:
    """Step 4: the gain where it matters: camera whites of the measured cameras, and simulated retrievals.

    Parameters
    ----------
    e_test
        Held-out spectra (N × 61, unit mean).
    data
        The measured-daylight model fitted on the training spectra.
    split, seed
        The split that set ``e_test`` apart (recorded) and the seed of the simulated histories.
    simulate, n_histories, n_frames, n_patches, time_budget_s, solver_kwargs
        As :func:`illumon.reports.daylight.daylight_report` documents them.

    Returns
    -------
    dict
        The ``gain`` section of the report's summary, or a ``skipped`` reason without the measured data.
    """
    gain: dict = {"split": split, "seed": seed}
    try:
        have_data = datasets.shared_data_dir() is not None
    except Exception:  # pragma: no cover - an unreadable data location means no data
        have_data = False
    if have_data:
        cams = [datasets.load_camera(c) for c in datasets.camera_names()]
        cw = _camera_white_gain(e_test, data, cams)
        gain["camera_white_at_true_chromaticity"] = {
            k: {"median_deg": q(v), "p95_deg": q(v, 95)} for k, v in cw.items()
        }
        gain["camera_white_n"] = int(cw["cie"].size)
        if simulate and n_histories > 0:
            sim = _simulate_gain(e_test, data, n_histories=n_histories, n_frames=n_frames, n_patches=n_patches,
                                 seed=seed, time_budget_s=time_budget_s, solver_kwargs=solver_kwargs)
            pm = sim["per_model"]
            gain["retrieval"] = {
                "n_histories": len(sim["histories"]), "n_frames": n_frames, "n_patches": n_patches,
                "seconds": sim["seconds"],
                **{k: {"median_angular_deg": q(v["angular"]), "mean_angular_deg": float(np.mean(v["angular"]))
                       if v["angular"] else float("nan"),
                       "median_spectral_rmse": q(v["rmse"]), "median_gfc": q(v["gfc"])} for k, v in pm.items()},
                "histories": sim["histories"],
            }
    else:
        gain["skipped"] = "measured cameras and reflectances not found (illumon.simulation.datasets.shared_data_dir() is None)"

    return gain
