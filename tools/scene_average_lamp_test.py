"""The lamp test (:func:`illumon.model.lamps.lamp_posterior`) with three forms of the scene average, on development
simulator histories whose lights and surfaces are known (issue 28, branch diag7).

* ``white+a`` — each light's camera white plus one offset ``a`` for the whole history, ``a``'s prior where measured
  surfaces average (:func:`illumon.model.lamps.expected_scene_offset`): the test as it is;
* ``learned`` — each light's scene average as the fitted model predicts it: the camera times the mean learned
  reflectance of the patches (the model's predictions are linear in the reflectances), ``a`` the residual, prior
  0 ± :data:`~illumon.model.lamps.SCENE_OFFSET_SD`;
* ``true`` — the same through the simulator's own mean reflectance: the scene average every light really gives (up
  to the pipeline), what no estimate of the light's move of the scene average can improve on.

Each history is fitted once with the measured camera (:func:`illumon.model.fit_scene_model`, its own lamp rounds) and
its frame means (:func:`illumon.model.lamps._frame_means`) judged by the three forms; only the given camera's test is
run (the diagnosis takes the smaller of it and an unmeasured camera's), on the whole history's grid posterior (not the
frame-by-frame verdicts :func:`~illumon.model.lamps.frame_verdicts` gives). Per history: frames judged ≥ 0.5 among the
lamp-lit ones and among the others, their ranges, and the offset's posterior.

    python tools/scene_average_lamp_test.py imgsim:none:141 imgsim:none:49 illumon:off_locus_illuminant:3 \
        majority:4 majority:6

``SIM:EFFECT:I`` is ``benchmarks/diagnose.py --split dev``'s ``I``-th history of ``EFFECT``; ``majority:I`` is
``benchmarks/lamp_majority.py``'s ``I``-th majority history. For lamp-lit histories each form's *departure* is printed
too: how far the lamp-lit frames' scene averages lie from where the form puts them under their true light, beyond the
daylight frames' own residual (median and largest |·|, log r/g and b/g), for the measured camera and for the camera
nobody measured (the diagnosis's second test, ``fit_scene_model(obs, None)``).

``--diagnose`` runs :func:`illumon.diagnosis.diagnose` itself on each history under each form (the lamp test's
``history_lamps`` and per-frame verdicts replaced within this process; the library is not changed): ``white+a``
(as it is), ``learned`` and ``true`` for every camera, and ``learned/measured`` and ``true/measured`` for the
measured camera's test only (the camera nobody measured keeps ``white+a``). It prints the effects named and the
off-locus frames' ``non_daylight``.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import sys
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "core"), str(ROOT / "benchmarks")]

from illumon.diagnosis.fit import diagnose  # noqa: E402
from illumon.model import fit as model_fit  # noqa: E402
from illumon.model import fit_scene_model  # noqa: E402
from illumon.model import lamps as L  # noqa: E402
from illumon.priors.scene_average import log_chroma  # noqa: E402
from illumon.simulation.effects import DEV_CAMERAS, hide_effect  # noqa: E402


def _history(spec: str):  # noqa: ANN202
    """(observations, sensitivities, illuminants, reflectances, lamp-lit frame indices) of ``spec``."""
    sim, *rest = spec.split(":")
    if sim == "majority":
        i = int(rest[0])
        h = hide_effect("off_locus_illuminant", DEV_CAMERAS[i % len(DEV_CAMERAS)], 5000 + i, frames=36,
                        lamp_frames="majority")
        return (h.observations, h.history.sensitivities, h.history.illuminants, h.history.reflectances,
                h.parameters["frames"])
    import diagnose
    import imgsim
    import rawsim

    effect, i = rest[0], int(rest[1])
    cam = rawsim.DEV_CAMERAS[i % len(rawsim.DEV_CAMERAS)]
    seed = diagnose.DEV_SEED0 + 1000 * diagnose.EFFECTS.index(effect) + i
    if sim == "imgsim":
        h = imgsim.hide_effect_img(effect, cam, seed, split="dev")
        return h.observations, h.sensitivities, h.illuminants, h.reflectances, h.parameters.get("frames", [])
    if sim == "illumon":
        h = hide_effect(effect, cam, seed)
        return (h.observations, h.history.sensitivities, h.history.illuminants, h.history.reflectances,
                h.parameters.get("frames", []))
    raise SystemExit(f"unknown history {spec!r} (illumon, imgsim or majority)")


def _scene_camera(model, obs) -> np.ndarray:  # noqa: ANN001
    """The model's camera times the mean learned reflectance of its patches ``obs`` shows (61 × 3)."""
    index = {p: i for i, p in enumerate(model.patches)}
    mi = [index[p] for p in obs.patches if p in index]
    rbar = model.basis @ model.coefficients[mi].mean(axis=0)
    return np.asarray(model.sensitivities, dtype=float) * np.clip(rbar, 1e-4, None)[:, None]


def _departure(obs, css, lights, refl, lit) -> str:  # noqa: ANN001
    """Each form's lamp-lit frames' departure from the scene average it predicts under their true light, for the
    measured camera and the camera nobody measured."""
    out = []
    for name, camera in (("measured", css), ("unmeasured", None)):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            model = fit_scene_model(obs, camera)
        g = log_chroma(L._frame_means(model, obs, np.asarray(model.history_estimate[0].info["theta"], dtype=float)))
        for form, cam in (("white+a", model.sensitivities), ("learned", _scene_camera(model, obs)),
                          ("true", np.asarray(model.sensitivities, dtype=float) * refl.mean(axis=0)[:, None])):
            r = g - log_chroma(lights @ cam)
            dev = np.abs(r[lit] - np.median(r[~lit], axis=0))
            out.append(f"    {name:10s} {form:8s} departure median ({np.median(dev[:, 0]):.3f}, {np.median(dev[:, 1]):.3f})"
                       f" max ({dev[:, 0].max():.3f}, {dev[:, 1].max():.3f}); daylight frames' spread "
                       f"({r[~lit, 0].std():.3f}, {r[~lit, 1].std():.3f})")
    return "\n".join(out)


@contextlib.contextmanager
def _form(form: str, mean_reflectance: np.ndarray):
    """The lamp test of :mod:`illumon.model.lamps` judging through ``form``'s scene camera within this process."""
    if form == "white+a":
        yield
        return
    source, _, cameras = form.partition("/")

    def camera(model, obs) -> np.ndarray:  # noqa: ANN001
        if source == "true":
            return np.asarray(model.sensitivities, dtype=float) * np.clip(mean_reflectance, 1e-4, None)[:, None]
        return _scene_camera(model, obs)

    def history_lamps(model, obs):  # noqa: ANN001, ANN202
        res = model.history_estimate[0] if model.history_estimate is not None else model.estimate(obs)[0]
        means = L._frame_means(model, obs, np.asarray(res.info["theta"], dtype=float))
        unbalanced = L._unbalanced_offset(model, means)
        camera_sd = float(model.camera.get("white_sd_log", 0.0) or 0.0)
        s = math.hypot(L.SCENE_OFFSET_SD, camera_sd)
        prior, css = unbalanced, model.sensitivities
        scene = unbalanced is None and (cameras != "measured" or model.camera.get("calibration") == "measured")
        if scene:
            css, prior = camera(model, obs), (np.zeros(2), np.array([s, s]))
        elif prior is None:
            prior = (L.expected_scene_offset(model, obs), np.array([s, s]))
        lp = L.lamp_posterior(means, css, model.daylight_model(), camera_sd=camera_sd, offset_prior=prior)
        nd = lp.non_daylight
        offset, offset_sd = unbalanced if unbalanced is not None else (lp.offset, lp.offset_sd)
        model.lamps = {"offset": offset.tolist(), "offset_sd": offset_sd.tolist(), "prior": L.LAMP_PRIOR,
                       "daylight_frames": int(np.sum(np.isfinite(nd) & (nd < 0.5))), "frames": int(len(nd)),
                       "scene_camera": bool(scene)}
        return L.HistoryJudgement(nd, means)

    def judged_frames(model, obs, theta, solver=None, means=None):  # noqa: ANN001, ANN202
        lamps = model.lamps
        prior = float(lamps.get("prior", L.LAMP_PRIOR))
        if means is None:
            means = L._frame_means(model, obs, theta, solver)
        css = camera(model, obs) if lamps.get("scene_camera") else model.sensitivities
        lp = L.frame_lamp_posterior(means, css, model.daylight_model(), np.asarray(lamps["offset"]),
                                    np.maximum(np.asarray(lamps["offset_sd"]), 0.01), prior=prior)
        return lp, np.where(np.isfinite(lp.non_daylight), lp.non_daylight, prior)

    saved = (L.history_lamps, model_fit.history_lamps, L._judged_frames)
    L.history_lamps = model_fit.history_lamps = history_lamps
    L._judged_frames = judged_frames
    try:
        yield
    finally:
        L.history_lamps, model_fit.history_lamps, L._judged_frames = saved


FORMS = ("white+a", "learned", "true", "learned/measured", "true/measured")


def diagnose_forms(spec: str) -> None:
    """The diagnosis of ``spec`` under every form of :data:`FORMS`."""
    obs, css, _, refl, lamp_frames = _history(spec)
    for form in FORMS:
        with _form(form, refl.mean(axis=0)), warnings.catch_warnings():
            warnings.simplefilter("ignore")
            d = diagnose(obs, css, reestimate=False)
        off = next((e for e in d.effects if e["effect"] == "off_locus_illuminant"), None)
        frames = "" if off is None else (f"  off-locus frames {len(off['parameters']['frame_indices'])} "
                                         f"(lamp-lit {len(set(off['parameters']['frame_indices']) & set(lamp_frames))}),"
                                         f" non_daylight {_range(off['parameters']['non_daylight'], 2)}")
        print(f"{spec} {form:17s} {[e['effect'] for e in d.effects] or ['none']}{frames}", flush=True)


def judge(spec: str) -> None:
    """Print the three forms' verdicts on ``spec``."""
    obs, css, lights, refl, lamp_frames = _history(spec)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = fit_scene_model(obs, css)
    means = L._frame_means(model, obs, np.asarray(model.history_estimate[0].info["theta"], dtype=float))
    g = log_chroma(means)
    lit = np.zeros(len(g), dtype=bool)
    lit[np.asarray(lamp_frames, dtype=int)] = True
    dm = model.daylight_model()
    true_white = log_chroma(lights @ css)
    true_scene = log_chroma(lights @ (css * refl.mean(axis=0)[:, None]))
    print(f"{spec}: {len(g)} frames, {int(lit.sum())} lamp-lit; true offset of white+a over the daylight frames "
          f"{_range(g[~lit] - true_white[~lit])}")
    forms = (("white+a", model.sensitivities, L.expected_scene_offset(model, obs), g - true_white),
             ("learned", _scene_camera(model, obs), np.zeros(2), None),
             ("true", css * refl.mean(axis=0)[:, None], np.zeros(2), g - true_scene))
    for name, cam, mu, true_offset in forms:
        lp = L.lamp_posterior(means, cam, dm, offset_prior=(mu, np.full(2, L.SCENE_OFFSET_SD)))
        nd = lp.non_daylight
        line = (f"  {name:8s} offset ({lp.offset[0]:+.3f}, {lp.offset[1]:+.3f}) ± {lp.offset_sd.max():.3f}"
                f"  daylight frames >= 0.5: {int(np.sum(nd[~lit] >= 0.5))}/{int((~lit).sum())}"
                f" (max {np.nanmax(nd[~lit]):.2f})")
        if lit.any():
            line += f"  lamp-lit >= 0.5: {int(np.sum(nd[lit] >= 0.5))}/{int(lit.sum())} ({_range(nd[lit], 2)})"
        if true_offset is not None:
            line += f"  true offset {np.round(np.median(true_offset, axis=0), 3).tolist()}"
        print(line, flush=True)
    if lit.any():
        print(_departure(obs, css, lights, refl, lit), flush=True)


def _range(v: np.ndarray, digits: int = 3) -> str:
    v = np.asarray(v, dtype=float)
    if v.ndim == 1:
        return f"{np.nanmin(v):.{digits}f}–{np.nanmax(v):.{digits}f}"
    return ", ".join(_range(v[:, k], digits) for k in range(v.shape[1]))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("histories", nargs="+", help="SIM:EFFECT:I (illumon, imgsim; --split dev) or majority:I")
    ap.add_argument("--diagnose", action="store_true", help="run the diagnosis under each form instead")
    args = ap.parse_args(argv)
    for spec in args.histories:
        (diagnose_forms if args.diagnose else judge)(spec)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
