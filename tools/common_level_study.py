"""What sets the scene model's common daylight level (issue 17): Granada run statistics and a prior comparison.

Static patches of unknown reflectance fix a history's *relative* illuminants but hardly the level common to all its
frames (a smooth spectral tilt of every illuminant and the inverse tilt of every reflectance leave the camera values
unchanged), so the priors set it. This script measures, on the development split only (``benchmarks/rawsim.py``):

1. Granada daylight (spectra 0–1299) in runs drawn as :func:`rawsim.daylight_run` draws them: the spread of a run's
   mean reciprocal temperature and Duv offset between runs and the spread within a run. A hierarchical prior
   (θ_f = μ + δ_f, ``CIEDaylight(mired_between=…, duv_between=…)``) takes its between-run spread from these ratios.
2. Histories of the ten static surfaces of ``benchmarks/regions_setup.py``'s scenes (patch means rendered from the
   measured spectra, linear, 40 frames) fitted with :func:`illumon.model.fit_scene_model` under (a) the shipped
   independent per-frame prior, (b) the hierarchical prior, (c) an oracle pinning the common reciprocal temperature to
   the truth: camera-white error and the error of the common reciprocal temperature (estimated minus true run mean).

    python tools/common_level_study.py [--seeds 8] [--split dev]
"""

from __future__ import annotations

import argparse
import os
import sys
import warnings
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import rawsim  # noqa: E402
from illumon.camera import angular_error_deg, camera_white, render  # noqa: E402
from illumon.daylight import CIEDaylight, cct_duv_from_xy, daylight_locus_duv, xy_from_spectrum  # noqa: E402
from illumon.model import IdentifiabilityWarning, fit_scene_model  # noqa: E402
from illumon.observations import Observations  # noqa: E402
from regions_setup import MARGIN, TexturedScene  # noqa: E402


def mired_delta(spectra: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Reciprocal temperature (MK⁻¹) and offset from the CIE daylight locus of spectra (F × 61)."""
    cct, duv = cct_duv_from_xy(xy_from_spectrum(spectra))
    return 1e6 / cct, duv - daylight_locus_duv(cct)


def run_statistics(split: str, frames: int, runs: int = 2000) -> dict:
    """Between-run and within-run spread of Granada runs of ``frames`` spectra (every 1st…3rd acquisition)."""
    pool = rawsim.daylight_pool(split)
    m, d = mired_delta(pool)
    rng = np.random.default_rng(0)
    means, var = [], []
    for _ in range(runs):
        stride = int(rng.integers(1, 4))
        start = int(rng.integers(0, len(pool) - stride * frames))
        idx = np.arange(start, start + stride * frames, stride)
        means.append([m[idx].mean(), d[idx].mean()])
        var.append([m[idx].var(), d[idx].var()])
    means, var = np.array(means), np.array(var)
    return {"all_sd": np.array([m.std(), d.std()]), "all_mean": np.array([m.mean(), d.mean()]),
            "between_sd": means.std(0), "within_sd": np.sqrt(var.mean(0))}


class PinnedCommon(CIEDaylight):
    """Oracle: the shipped prior on each frame's deviation from the history's mean, the mean pinned to ``common``."""

    def __init__(self, common: float) -> None:
        super().__init__()
        self.common = common

    def history_prior_cost(self, params: np.ndarray) -> float:
        m = params[:, 0]
        return float(((m - m.mean()) ** 2).sum() / self.mired_sigma**2 + ((m.mean() - self.common) / 0.5) ** 2
                     + ((params[:, 1] / self.duv_sigma) ** 2).sum())


def history(camera: str, split: str, seed: int, frames: int = 40) -> tuple[Observations, np.ndarray, np.ndarray]:
    """Patch means of a scene's ten static surfaces (texture averaged, auto-exposed, 0.3 % noise) and the daylight."""
    scene = TexturedScene(camera, split, seed, frames)
    rng = np.random.default_rng(seed + 7)
    tex = np.array([scene.texture[y + MARGIN : y + h + MARGIN, x + MARGIN : x + w + MARGIN].mean()
                    for x, y, w, h in scene.surfaces])
    values = []
    for e in scene.daylight:
        rgb = render(scene.css, e, scene.surfaces_refl[:10]) * tex[:, None]
        rgb *= 0.8 / np.percentile(render(scene.css, e, scene.surfaces_refl), 99) * np.exp(0.05 * rng.standard_normal())
        values.append(np.clip(rgb * (1 + 0.003 * rng.standard_normal(rgb.shape)), 0, 1))
    obs = Observations([f"f{i}" for i in range(frames)], [f"s{j}" for j in range(10)], np.array(values))
    return obs, scene.css, scene.daylight


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--split", choices=("dev", "score"), default="dev")
    ap.add_argument("--seeds", type=int, default=8, help="scenes per camera (every other camera of the split)")
    ap.add_argument("--frames", type=int, default=40)
    args = ap.parse_args()
    from illumon.simulation import datasets

    if datasets.shared_data_dir() is None:
        print("common_level_study: measured data (../shared/data) not available", file=sys.stderr)
        return 2
    st = run_statistics(args.split, args.frames)
    print(f"Granada {args.split}, runs of {args.frames}: mired mean {st['all_mean'][0]:.1f}, sd {st['all_sd'][0]:.1f} "
          f"(between runs {st['between_sd'][0]:.1f}, within {st['within_sd'][0]:.1f}); Duv offset mean "
          f"{st['all_mean'][1]:.5f}, sd {st['all_sd'][1]:.5f} (between {st['between_sd'][1]:.5f}, within "
          f"{st['within_sd'][1]:.5f})")
    shipped = CIEDaylight()
    ratio = st["between_sd"] / st["all_sd"]
    hier = CIEDaylight(mired_between=float(ratio[0] * shipped.mired_sigma), duv_between=float(ratio[1] * shipped.duv_sigma))
    print(f"hierarchical prior: mired between {hier.mired_between:.1f} of {hier.mired_sigma:.0f}, Duv between "
          f"{hier.duv_between:.5f} of {hier.duv_sigma}; the independent prior's common sd for {args.frames} frames: "
          f"{shipped.mired_sigma / np.sqrt(args.frames):.1f} MK⁻¹, {shipped.duv_sigma / np.sqrt(args.frames):.5f}")
    pool = rawsim.DEV_CAMERAS if args.split == "dev" else rawsim.SCORE_CAMERAS
    priors = {"independent (shipped)": lambda _m: shipped, "hierarchical": lambda _m: hier,
              "oracle common mired": PinnedCommon}
    results: dict[str, list[tuple[float, float]]] = {k: [] for k in priors}
    prior_only = []
    for s in range(args.seeds):
        for ci, cam in enumerate(pool[::2]):
            obs, css, daylight = history(cam, args.split, 5000 + 100 * s + ci, args.frames)
            true_m, _ = mired_delta(daylight)
            white = np.array([camera_white(css, e) for e in daylight])
            prior_only.append(true_m.mean() - shipped.mired_mean)
            for name, make in priors.items():
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", IdentifiabilityWarning)
                    model = fit_scene_model(obs, css, daylight=make(true_m.mean()))
                res, _ = model.history_estimate
                err = np.median([angular_error_deg(w, t) for w, t in zip(res.white, white, strict=True)])
                results[name].append((float(err), float(np.mean(1e6 / res.cct) - true_m.mean())))
    n = len(prior_only)
    print(f"\n{n} scenes ({args.split}); the prior mean alone would miss the common mired by "
          f"{np.sqrt(np.mean(np.square(prior_only))):.1f} MK⁻¹ rms")
    print(f"{'prior':<24} {'white med ° (median)':>20} {'p90':>6} {'> 1°':>6} {'common Δmired rms':>18} {'mean':>6}")
    for name, rows in results.items():
        r = np.array(rows)
        print(f"{name:<24} {np.median(r[:, 0]):>20.3f} {np.percentile(r[:, 0], 90):>6.2f} {np.mean(r[:, 0] > 1):>6.2f} "
              f"{np.sqrt(np.mean(r[:, 1] ** 2)):>18.1f} {r[:, 1].mean():>+6.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
