"""Fitting a scene model to a history: block coordinate descent on the joint posterior.

Fitting alternates two exact sub-problems of the joint model of :mod:`illumon.retrieval.joint` (Marguier & Süsstrunk's
model with an 8-component reflectance basis): the reflectances given all illuminants and exposures (linear Gaussian
posterior, Kinoshita & Kiya eqs. 13–14 in basis coefficients), then every frame's daylight and exposure given the
reflectances (:class:`~.solver.FrameSolver`), with over-relaxation and common-shift candidates along the directions
in which the alternation crawls. Long histories are fitted on a subsample of frames spread over the illuminant range.
A camera nobody measured, or one with references of known reflectance, is fitted jointly with its transform
(:mod:`illumon.camera.calibration`).

References
----------
.. [Marguier2007] Marguier & Süsstrunk, CIC 2007: the joint model.
.. [Kinoshita2023] Kinoshita & Kiya, 2023: eqs. 13–14 in basis coefficients.
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Callable, Mapping

import numpy as np
from numpy.typing import NDArray
from scipy.linalg.lapack import dposv

from .._blas import single_blas_thread
from ..camera import formation
from ..camera.balance import self_balance_warning, unbalanced_warning
from ..camera.calibration import (
    SCENE_AVERAGE_SD,
    calibrate_scene_model,
    held_or_bent,
    history_length_regime,
    prior_sensitivities,
    prior_white_spread,
)
from ..camera.primaries import (
    SRGB_BALANCE_SD,
    check_primaries,
    daylight_prior_for,
    output_space_warning,
    srgb_sensitivities,
    to_srgb_primaries,
)
from ..camera.references import check_known_reflectances, coloured_only, coloured_only_warning
from ..daylight import CIEDaylight
from ..observations import Observations, observed, sd_variance
from ..priors import CameraPrior, ReflectanceBasis, reflectance_basis
from ..priors.scene_average import scene_average_evidence
from ..retrieval.common import censored, grey_world_mired, imaging_operators, white_level
from ..spectra import GRID
from .identifiability import IdentifiabilityWarning, identifiability, spread_subsample
from .intervals import MODEL_ERROR, VERDICT_KEYS, widen_cct_intervals, widen_white_intervals
from .lamps import (
    LAMP_PRIOR,
    HistoryJudgement,
    apply_lamps,
    evidence_frames,
    history_lamps,
    lamp_population,
    unbalanced_probability,
)
from .level import (
    anchor_common_level,
    common_level_posterior,
    daylight_level,
    mean_log_chroma,
    scene_reading,
    verdict_shift,
)
from .scene import SceneModel
from .solver import FrameSolver, flare_scales

__all__ = ["fit_scene_model", "LAMP_ROUNDS", "MIN_LAMP_SHARE"]

FLARE_SD_MIN, FLARE_SD_MAX = 0.01, 0.12
"""Bounds of a history's learned glare spread (:meth:`_JointObjective.learn_flare_sd`): 0.12 is the root mean square
of the offsets measured on the development photographs (``benchmarks/flare.py``), 0.01 keeps a little of the offset
every lens has where a history shows none."""

LAMP_ROUNDS = 3
"""Rounds of judging the frames' light and refitting the scene without the lamp-lit ones (:mod:`.lamps`)."""

BORDERLINE = 0.01
"""A lamp round whose frames left out differ from the last round's only by frames whose ``non_daylight`` lies within
this of :data:`~.lamps.LAMP_PRIOR`, now and in the last judgement, refits nothing (:func:`_refit_without_lamp_frames`).
A daylight history has many frames near the prior (the benchmark's 2k: 149 within 0.01), and a refit moves them by a
few 1e-4, so such frames flip across it from round to round: the 2k history's second refit left out the same 276 frames
but two (non_daylight 0.2499 ↔ 0.2502), a 1k history's third refit went back to its first set. Each such refit cost a
whole scene fit and moved the whites by the fit's own spread (issue 29: on 30 benchmark histories of 1k, 2k and 5k
frames 104 → 60 scene fits, whites moved by at most 0.30°, the mean of their median errors 0.816 → 0.807°). 0
restores refitting on every change."""


MEASURED_WHITE_SD = 0.02
"""Spread (log r/g, b/g) of a measured camera's daylight whites in the lamp-lit test of :mod:`.level`: the camera
is known, the spread is its measurement's."""

FIT_LEVEL_SD = 0.043
"""Error (log r/g, b/g, RMS) of a measured camera's daylight fit's common level — what the reflectance prior makes of
the scene: 0.048 / 0.035 on histories of measured surfaces, 0.050 / 0.037 on the same made pale
(:func:`rawsim.pale`), development cameras × 2 seeds, both simulators (``benchmarks/unmeasured.py``'s ``none`` case
with the sensitivities given). The scene average's reading was 0.058 / 0.153 off on the first (its stated spread
0.147) and 0.005 / 0.021 on the second (stated 0.038)."""

FEW_FRAMES_LEVEL = 3
"""A sensor-RGB camera nobody measured, judged daylight, joins its fit's level with the scene average's reading
(:func:`~.level.daylight_level`, as a measured sensor always does) when its history is this short or shorter in
:func:`~illumon.camera.calibration.history_length_regime`'s terms (one to four frames). Over so few frames the fit's
level is the reflectance prior's mean surface and nothing else, and a scene that averages near grey — walls, a table,
an indoor room under warm light — reads bluer than its light. On the real chart-free photographs
(``benchmarks/real_pairs.py``, two frames, raw sensor) the pale wall of ``scene002`` went 4.75 → 2.07° (gray-world
over the same regions 1.44°). Development histories (``python benchmarks/unmeasured.py --split dev --seeds 1 --frames
F --cases none,pale,raw+lamps,none+matrix,grey``, ``illumon`` / ``rawsim`` medians): pale daylight scenes 2.26 / 2.10
→ 1.38 / 1.36° on one frame, 0.98 / 1.07 → 0.77 / 0.79° on three; lamp-lit ones judged daylight 0.90 / 0.82 → 0.80 /
0.78° on three (on one, max 3.6 / 3.5 → 2.0 / 2.0°); every other case identical. On six frames the pale scenes went
0.58 / 0.55 → 0.87 / 0.85° and on thirty 0.59 / 0.50 → 0.75 / 0.72°: longer histories keep the fit's level alone.
The joined level pins such a camera's white, not its light's temperature (its channel scales are unknown), so the
temperature keeps the fit's own uncertainty: narrowed to the level's, the pale three-frame histories' 95 % CCT
intervals held 0.86 / 0.81 of the lights (0.95 / 0.86 before the change), kept, 1.00 / 0.93."""

FEW_FRAMES_FIT_LEVEL_SD = {1: 0.110, 3: 0.082}
"""Error (log r/g, b/g, RMS) of the fit's level of a sensor-RGB camera nobody measured over a few frames, by
:func:`~illumon.camera.calibration.history_length_regime` (one frame; two to four): what :func:`~.level.daylight_level`
weighs that level with for :data:`FEW_FRAMES_LEVEL`, in place of :data:`FIT_LEVEL_SD` (a measured camera's, on
histories whose light varies). Measured by ``python tools/fit_level_spread.py --frames 1,3 --seeds 4 --unmeasured``
(development cameras, the prior without the camera's maker, both simulators, daylight histories of measured surfaces
and of pale ones, pooled): 0.110 on one frame (measured surfaces 0.121, pale 0.096), 0.082 on three (0.092, 0.070);
re-measured with these values in place (the first fit's level moves the camera's channel scales the refit's level
is read through), 0.115 and 0.085.
Held at 0.043 the fit's level outweighed a scene average read to 0.04–0.08: the scene's reading joined with a
quarter of its weight or less, and the real chart-free rooms (``benchmarks/real_pairs.py``, raw, two frames) kept
the reflectance prior's warm mean surface, 0.17–0.22 off their light. Development (``python benchmarks/unmeasured.py
--split dev --seeds 1 --frames F --cases none,pale,raw+lamps``, ``illumon`` / ``rawsim`` medians): pale 1.38 / 1.36
→ 0.57 / 0.52° (one frame), 0.77 / 0.79 → 0.64 / 0.60° (three); lamp-lit judged daylight 0.68 / 0.63 → 0.72 / 0.74°
(one frame; maxima 2.0 / 2.0 → 0.97 / 1.15°), 0.80 / 0.78 → 0.71 / 0.65° (three; p95 4.5 / 4.2 → 2.4 / 1.8°);
``none`` identical. Real: ``real_pairs.py`` raw without a reference 7.44 / 5.66 / 2.07 → 6.10 / 4.48 / 2.07°;
``real.py`` identical, ``real.py --single`` ``sony-raw`` without a reference 3.49 → 2.64°."""

MIN_LAMP_SHARE = 0.02
"""A history's frames start being left out of the reflectance fit (:func:`_refit_without_lamp_frames`) only when the
frames judged lamp-lit (``non_daylight`` > 0.5) make up at least this share of the frames the reflectances were fitted
on (all of a short history's, the 300-frame subsample of a long one's); fewer are fitted as a daylight history. A
clean daylight history has frames that cross 0.5 by chance (the refit benchmark's 2k history: 7, four of them in
its subsample), and leaving out every frame above the prior (276) and refitting cost a whole scene fit and moved the
whites by the fit's own spread — for the worse on average. Chosen on development histories (issue 29): the
benchmark's daylight histories of 1k, 2k and 5k frames (seeds 1–10) have 0–4 such frames in their subsample (at most
1.3 %), every development lamp history (``off_locus_illuminant`` of :func:`illumon.simulation.effects.hide_effect`,
the six development cameras, seeds 0–4 at its default 24–40 frames and 0–3 at 300 and 1 000 frames, 78 histories)
at least 2.3 % (7 of 300), so 2 % changes no lamp history's rounds. On the daylight ones, without the refit the mean
of the median camera-white errors 0.807 → 0.635° and of the p95s 1.009 → 0.830° (23 of 30 better), 60 → 30 scene
fits. A history of 50 frames or more now needs more than one such frame (one of 60 is 1.7 %): ``online.py --quick``'s
60-frame morning histories, illumon p95 / max 1.87 / 3.84 → 1.64 / 2.08°, rawsim median 0.59 → 0.61° (p95, max the
same). Later rounds (frames already left out) are unchanged."""

ROBUST_ROUNDS = 3
"""Rounds of leaving frames no daylight explains out of the reflectance fit (:func:`_frames_explained`): the
booth's cool-white frame goes first, its TL84 frame (explained well while the reflectances bend for the cool-white
one: misfit 3 × the median) in the next."""

FRAME_COST_RATIO = 6.0
"""A frame's misfit over the history's median frame above which it is a candidate to leave out: chosen on the
development cameras' booth (``benchmarks/lightbox.py``: cool-white frames 6–10 ×, TL84 frames 14–16 × once it
is out)."""

FRAME_COST_FLOOR = 1.5
"""And a misfit (weighted squared residual per value) above which: a daylight frame fitted within the nominal
noise is never a candidate (fewer refits; the booth's candidates have 2.2–5.8)."""

FRAME_REFIT_GAIN = 3.0
"""The factor by which the kept frames' median misfit must fall for the refit without the candidates to be kept:
above every daylight history of ``benchmarks/unmeasured.py --split dev`` (at most 2.9, with and without glare),
below the booth's (median 4.0, 2.4 at least)."""


def _reflectance_posterior(
    a: NDArray[np.float64], y: NDArray[np.float64], w2: NDArray[np.float64], lam: NDArray[np.float64],
    mu: NDArray[np.float64], weighted: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Kinoshita & Kiya eqs. 13–14 in basis coefficients, for every patch at once.

    ``a`` (F × 3 × K) maps coefficients to each frame's responses, ``w2`` (F × P × 3) are noise precisions (0 where
    missing), ``lam``/``mu`` the prior precision and mean. Returns means (P × K) and precisions (P × K × K). The sums
    over frames and channels are matrix products (the three-operand einsums they replace took 7 × as long).
    ``weighted``: :func:`_weighted` of ``w2`` and ``y``, when the caller keeps it (they do not depend on ``a``).
    """
    prec, rhs = _normal_equations(a, _weighted(w2, y) if weighted is None else weighted, lam, mu)
    return np.linalg.solve(prec, rhs[..., None])[..., 0], prec


def _weighted(w2: NDArray[np.float64], y: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The precisions (P × F·3) and precision-weighted values :func:`_reflectance_posterior` sums over frames."""
    wt = w2.transpose(1, 0, 2).reshape(w2.shape[1], -1)
    return wt, wt * y.transpose(1, 0, 2).reshape(wt.shape)


def _normal_equations(a: NDArray[np.float64], weighted: tuple[NDArray[np.float64], NDArray[np.float64]],
                      lam: NDArray[np.float64], mu: NDArray[np.float64]
                      ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Every patch's reflectance precision (P × K × K) and information (P × K) given the frames' operators ``a``
    (F × 3 × K) and :func:`_weighted` sums, the prior included."""
    f, c, k = a.shape
    rows = a.reshape(f * c, k)
    wt, wty = weighted
    prec = (wt @ (rows[:, :, None] * rows[:, None, :]).reshape(f * c, k * k)).reshape(-1, k, k) + lam
    return prec, wty @ rows + lam @ mu


def _mean_green(y: NDArray[np.float64], present: NDArray[np.bool_]) -> NDArray[np.float64]:
    """Each frame's mean green over its present patches (F; 1 for a frame without any): ``np.mean`` of each frame's
    values bit for bit, the frames with the same number of patches at once (their patches gathered in order, summed
    over an axis of that length as ``np.mean`` sums them; a Python loop over a 300-frame fit's frames took ~5 ms)."""
    count = present.sum(axis=1)
    level = np.ones(len(y))
    for k in np.unique(count[count > 0]).tolist():
        rows = np.flatnonzero(count == k)
        which = np.argsort(~present[rows], axis=1, kind="stable")[:, :k]  # the present patches, in order
        level[rows] = y[rows[:, None], which, 1].sum(axis=1) / k
    return level


def fit_scene_model(
    obs: Observations,
    sensitivities: NDArray[np.float64] | None,
    *,
    known_reflectances: Mapping[str, NDArray[np.float64]] | None = None,
    camera_prior_mean: NDArray[np.float64] | None = None,
    camera_prior: CameraPrior | None = None,
    rendered_camera_prior: CameraPrior | None = None,
    primaries: str = "camera",
    daylight: CIEDaylight | None = None,
    relative_error: float = 0.02,
    absolute_error: float = 0.002,
    max_fit_frames: int = 300,
    iterations: int = 40,
    tol: float = 0.01,
) -> SceneModel:
    """Learn a :class:`SceneModel` from a history (see module docstring for the method).

    Parameters
    ----------
    obs
        Observations of static patches (each patch seen in at least one frame), linear, in the camera's output
        space. A single frame is fitted too: its patches' reflectances are then the prior's reading of one view (a
        Bayesian gray-world, Kinoshita & Kiya's single-image estimate), or the references' where it shows them.
    sensitivities
        Measured camera sensitivities on the grid (61 × 3), or ``None`` for a camera nobody measured: then the prior
        from the measured cameras is used and refined from the data (:mod:`illumon.camera.calibration`).
    known_reflectances
        References of known reflectance (patch id → spectrum on the grid, 0…1) that appear in some frames of ``obs``,
        typically one: a grey card pins each channel's scale, a chart also a 3 × 3 colour matrix. Their patches are
        not part of the learned scene.
    camera_prior_mean
        With ``sensitivities=None``: the unmeasured camera's prior sensitivities (default: the mean of the measured
        cameras shipped with illumon, or for ``primaries="srgb"`` the linear-sRGB colour-matching functions).
    camera_prior
        The measured cameras' prior a chart's reading of its frame's light integrates an unmeasured sensor-RGB
        camera over (:mod:`illumon.camera.chart_light`; default the shipped prior of every measured camera;
        benchmarks pass one without the scored camera's maker).
    rendered_camera_prior
        The rendered cameras' prior a sensor-RGB camera's chart is read with when no sensor explains it (its colour
        matrix is on; default :func:`illumon.priors.rendered_camera_prior`; benchmarks pass one without the scored
        camera's maker). The model then warns that the chart looks rendered.
    primaries
        The camera's output space (:data:`illumon.camera.primaries.PRIMARIES`): ``"camera"`` (sensor RGB) or
        ``"srgb"`` (rendered output: white balance and a colour matrix to sRGB primaries). With ``"srgb"`` measured
        sensitivities are first carried to sRGB primaries by a white-preserving matrix
        (:func:`illumon.camera.primaries.to_srgb_primaries`).
    daylight
        CIE daylight model with its prior; the default :class:`~illumon.daylight.CIEDaylight`.
    relative_error, absolute_error
        Noise model before the residual-based scale factor.
    max_fit_frames
        Histories longer than this fit reflectances on that many frames spread over the gray-world illuminant range.
    iterations, tol
        Alternation cap and convergence tolerance (MK⁻¹, largest change of any frame's reciprocal temperature).

    Returns
    -------
    SceneModel
        Its ``camera`` says how the camera was calibrated; estimates and gains are in the observations' RGB space.
    """
    check_primaries(primaries)
    if daylight is None and primaries == "srgb":
        daylight = daylight_prior_for(primaries)
    balance_sd = SRGB_BALANCE_SD if primaries == "srgb" else None
    kwargs = dict(daylight=daylight, relative_error=relative_error, absolute_error=absolute_error,
                  max_fit_frames=max_fit_frames, iterations=iterations, tol=tol,
                  balance_sd=balance_sd)
    known = check_known_reflectances(known_reflectances, "known reflectances") if known_reflectances else {}
    missing = [p for p in known if p not in obs.patches]
    if missing:
        raise ValueError(f"known patch(es) never observed: {', '.join(missing)}")
    # a few colours without a neutral, for a camera nobody measured: estimated without them (where a scene remains)
    aside = (sorted(known) if sensitivities is None and coloured_only(known) and len(obs.patches) - len(known) >= 2
             else [])
    if aside:
        obs, known = obs.select_patches([p for p in obs.patches if p not in known]), {}
    if primaries == "srgb":
        sensitivities, camera_prior_mean = _in_srgb_primaries(sensitivities, camera_prior_mean)
    elif camera_prior is not None and camera_prior_mean is None:
        camera_prior_mean = camera_prior.mean

    def fit_once(o: Observations, estimate: Observations | None = None, rows: NDArray[np.intp] | None = None
                 ) -> SceneModel:
        extra = {} if estimate is None else {"estimate": estimate, "rows": rows}
        return _fit_camera_and_scene(o, sensitivities, known, (camera_prior_mean, camera_prior, rendered_camera_prior),
                                     primaries,
                                     {**kwargs, **extra})

    model = fit_once(obs)
    judged = None
    scene = obs.select_patches([p for p in obs.patches if p not in known]) if known else obs
    if not known and sensitivities is not None:  # an unmeasured camera's lamp verdicts are not to be acted on
        model, judged = _refit_without_lamp_frames(model, obs, fit_once)
    elif known and sensitivities is None and primaries == "camera":
        # sensor RGB calibrated by references: the lamp-lit frames bend the shared reflectances, and with them the
        # level every frame's temperature shares (a light booth: its D65 frame read as 22 900 K without the chart's
        # own reading, as a camera's colour matrix makes it refused; 6 030 K with the rounds). The reference frames
        # are always kept. Not for rendered output: on development daylight histories with a grey card
        # (``unmeasured.py --split dev --cases grey+rendered``) its verdicts left 3–16 of 30 frames out of 5 of the
        # 28 histories, medians 0.93 → 1.11° (rawsim) and 1.37 → 1.75° (illumon)
        shown = np.any(np.all(np.isfinite(obs.values[:, [obs.patches.index(p) for p in known]]), axis=-1), axis=1)
        model, judged = _refit_without_lamp_frames(
            model, scene, lambda _day, estimate, rows: fit_once(obs.subset(rows), estimate=obs, rows=rows),
            keep=shown)
    if judged is None:  # (a model the rounds judged last holds the verdicts of ``obs`` already: the same numbers)
        judged = history_lamps(model, scene)
    apply_lamps(model, scene, *model.history_estimate, means=judged.means)
    res = model.history_estimate[0] if model.history_estimate else None
    msg = self_balance_warning(obs.times, 1e6 / np.asarray(res.cct, dtype=float)) if res is not None else None
    if msg:
        model.identifiability.setdefault("warnings", []).append(msg)
        warnings.warn(msg, IdentifiabilityWarning, stacklevel=2)
        _light_unseen(model)
    msg = None
    if primaries == "camera" and RENDERED_CHART_WARNING not in model.identifiability.get("warnings", []):
        # rendered output declared sensor RGB (a chart says so itself), read where the lamp test reads its evidence
        msg = output_space_warning(scene.values[evidence_frames(len(scene.frames))])
    elif primaries == "srgb" and not known and unbalanced_probability(model) > 0.5 and "level" in model.noise:
        msg = unbalanced_warning(model.noise["level"])  # lamps throughout, or output that is not balanced srgb
    for m in (msg, coloured_only_warning(aside) if aside else None):
        if m:
            model.identifiability.setdefault("warnings", []).append(m)
            warnings.warn(m, IdentifiabilityWarning, stacklevel=2)
    return model


SELF_BALANCED_WHITE_SD = 0.025
"""Spread (log r/g, b/g) added to the camera white of rendered output with no reference whose light hardly changed
over a day (:func:`_light_unseen`: the camera balanced itself). Its automatic white balance leaves each frame a
residual of its own, which the history's balance prior — the mean white of a fixed pipeline near grey — does not know
of. Chosen on development histories (``benchmarks/unmeasured.py`` cases ``none+awb``, ``grey+awb`` and ``chart+awb``
with the frames' times over 24 hours, with and without veiling glare, both simulators, 14 cameras, one seed: 167
of the 168 read as self-balanced, none of 28 preset ones): 11.0 % of the 1 680 frames without a reference were
within 1°, stated 0.198; 0.025 states 0.110 and is also the spread of largest likelihood (log −627 → −579). With a
reference the same fit gives 0.006 (grey card: 26.8 % within, stated 0.290) and 0.002 (chart: 57.5 %, 0.585), within
0.02 of the stated figures, so nothing is added there."""


def _light_unseen(model: SceneModel) -> None:
    """A history whose light hardly changed colour over a day (:func:`~illumon.camera.balance.self_balance_warning`)
    was balanced by the camera — or lit by a steady lamp. If the camera balanced itself its output no longer shows the
    light's colour, so the light's temperature is known only as well as the daylight prior knows it: that prior's
    spread (``mired_sigma``, 45 MK⁻¹) joins every CCT interval, now and in the model's later estimates
    (``model_error["balanced_mired"]``). Measured on ``benchmarks/unmeasured.py``'s auto-balanced cases: the CCT
    intervals held the light's temperature in 22–47 % of frames (RMS error 31–38 MK⁻¹: the estimates read the
    balanced light, near D65), and in 94–99 % with the frames' times spread over eight hours (``--hours 8``), the
    preset cases' intervals unchanged. Rendered output with no reference, unless lit by lamps throughout
    (:mod:`.level`), also widens its camera white by :data:`SELF_BALANCED_WHITE_SD` (``model_error["camera_log_gain"]``,
    and so in its later estimates); with a reference the whites keep their intervals."""
    sd = float(model.daylight_model().mired_sigma)
    model.noise["model_error"] = dict(model.noise.get("model_error", MODEL_ERROR), balanced_mired=sd)
    if model.history_estimate is not None:
        widen_cct_intervals(model.history_estimate[0], model.history_estimate[1], sd)
    camera = getattr(model, "camera", None) or {}
    if (camera.get("calibration") == "none" and camera.get("primaries") == "srgb"
            and unbalanced_probability(model) <= 0.5):
        # rendered output, no reference, daylight: the camera's own balance moved from frame to frame, which the
        # history's balance prior (a fixed pipeline) does not know of
        me = model.noise["model_error"]
        me.update(camera_log_gain=float(math.hypot(me.get("camera_log_gain", 0.0), SELF_BALANCED_WHITE_SD)),
                  balanced_log_gain=SELF_BALANCED_WHITE_SD)
        if model.history_estimate is not None:
            widen_white_intervals(model.history_estimate[0], model.history_estimate[1], SELF_BALANCED_WHITE_SD)


def _in_srgb_primaries(sensitivities: NDArray[np.float64] | None, camera_prior_mean: NDArray[np.float64] | None
                       ) -> tuple[NDArray[np.float64] | None, NDArray[np.float64] | None]:
    """For rendered output: measured sensitivities carried to sRGB primaries
    (:func:`~illumon.camera.primaries.to_srgb_primaries`), or for a camera nobody measured the linear-sRGB
    colour-matching functions as its prior mean unless one is given."""
    if sensitivities is not None:
        sensitivities = to_srgb_primaries(np.asarray(sensitivities, dtype=float))
    if sensitivities is None and camera_prior_mean is None:
        camera_prior_mean = srgb_sensitivities()
    return sensitivities, camera_prior_mean

RENDERED_CHART_WARNING = (
    "the chart's colours are those of rendered output (a colour matrix to sRGB primaries), not of a sensor's RGB, "
    "and its light was read as such: if the camera applies a colour matrix, register it with primaries srgb")
"""The warning of a camera declared sensor RGB whose chart was read with the rendered cameras' prior
(:func:`illumon.camera.calibration._chart_readings`)."""


def _fit_camera_and_scene(o: Observations, sensitivities: NDArray[np.float64] | None,
                          known: Mapping[str, NDArray[np.float64]],
                          priors: tuple[NDArray[np.float64] | None, CameraPrior | None, CameraPrior | None],
                          primaries: str, kwargs: dict) -> SceneModel:
    """One scene fit of ``o``: through :func:`~illumon.camera.calibration.calibrate_scene_model` for a camera known
    only up to ``T`` (unmeasured, or with references), else the fixed-camera fit; ``camera`` records which.
    ``priors``: the unmeasured camera's prior mean and the sensor and rendered cameras' priors a chart's reading
    uses."""
    camera_prior_mean, camera_prior, rendered_prior = priors
    if not known and primaries == "camera":
        # sensor RGB without references: the level static patches cannot see is the camera's daylight, unless the
        # scene average says the history is lit by light no daylight through that camera gives (:mod:`.level`) — the
        # prior camera within the measured cameras' spread for one nobody measured, else the camera itself
        if sensitivities is None:
            base = prior_sensitivities() if camera_prior_mean is None else np.asarray(camera_prior_mean, dtype=float)
            kwargs = {**kwargs, "camera_level": (base, prior_white_spread(), False)}
        else:
            kwargs = {**kwargs, "camera_level": (np.asarray(sensitivities, dtype=float), MEASURED_WHITE_SD, True)}
    if sensitivities is None or known:
        # a refit of the daylight frames estimates every frame of ``estimate`` once, after the calibration
        target = {"estimate": kwargs.pop("estimate", None), "rows": kwargs.pop("rows", None)}
        m = calibrate_scene_model(o, sensitivities, known, lambda oo, c, **kw: _fit_fixed_camera(oo, c, **kwargs, **kw),
                                  prior_mean=camera_prior_mean, camera_prior=camera_prior,
                                  rendered_prior=rendered_prior, primaries=primaries, **target)
        if m.camera.get("chart_read_as") == "srgb" and primaries == "camera":
            m.identifiability.setdefault("warnings", []).append(RENDERED_CHART_WARNING)
            warnings.warn(RENDERED_CHART_WARNING, IdentifiabilityWarning, stacklevel=3)
    else:
        m, _ = _fit_fixed_camera(o, np.asarray(sensitivities, dtype=float), **kwargs)
        m.camera = {"calibration": "measured"}
    m.camera["primaries"] = primaries
    return m


def _refit_without_lamp_frames(model: SceneModel, obs: Observations, fit_once: Callable[..., SceneModel], *,
                               keep: NDArray[np.bool_] | None = None) -> tuple[SceneModel, HistoryJudgement | None]:
    """Light that is not daylight (:mod:`.lamps`): lamp-lit frames are left out of the reflectance fit when enough
    daylight frames remain to learn every patch; every frame is then judged against the refitted scene (a few rounds:
    frames forced onto daylight bend the reflectances, which can hide other lamp-lit frames). The rounds stop when
    the frames left out no longer change, or change only by frames within :data:`BORDERLINE` of the prior in both
    the last judgement and this one (coin flips: refitting on such a set is the same fit again). None is left out of
    a history whose frames judged lamp-lit are fewer than :data:`MIN_LAMP_SHARE` of those its reflectances were fitted
    on (chance crossings of a daylight history).

    Each refit estimates every frame of ``obs`` once (its training summary read from its daylight frames' rows),
    where it estimated its daylight frames and then every frame again; the previous model's estimate is let go
    before the refit, so no two estimates of the whole history are held at once.

    Returns the model and its judgement (:func:`~.lamps.history_lamps` of ``obs``, its verdicts in ``model.lamps``)
    when the rounds stopped on judging it, ``None`` when the last round refitted it (issue 29: the judgement repeated
    after the rounds cost ~30 ms of a 2k-frame refit; its frame means are reused by :func:`~.lamps.apply_lamps`).
    ``keep``: frames never left out (those showing a reference)."""
    lamp = np.zeros(len(obs.frames), dtype=bool)
    judged = np.full(len(obs.frames), np.nan)  # the non_daylight that chose ``lamp``
    for _ in range(LAMP_ROUNDS):
        # out of the reflectance fit, once some frame is more likely lit by a lamp than not: every frame whose
        # data favour a lamp (Bayes factor > 1, posterior above the prior) — a daylight frame lost costs little,
        # a lamp-lit frame kept bends every reflectance. A history with no lamp-lit frame is fitted as before.
        judgement = history_lamps(model, obs)
        nd = judgement.non_daylight
        new = nd > (LAMP_PRIOR if np.any(nd > 0.5) else 1.0)
        if keep is not None:
            new &= ~keep
        if not lamp.any() and model.fit_frames is not None and np.mean(nd[model.fit_frames] > 0.5) < MIN_LAMP_SHARE:
            return model, judgement  # too few of the frames the reflectances were learned from are lamp-lit: daylight
        day = obs.subset(np.flatnonzero(~new))
        if (np.array_equal(new, lamp) or not new.any() or (~new).sum() < max(2, 0.5 * len(new))
                or not np.all(day.present.any(axis=0))):
            return model, judgement  # nothing (new) to leave out, or a history judged mostly lamp-lit: no daylight
        moved = new != lamp
        if lamp.any() and np.all(np.abs(np.concatenate([nd[moved], judged[moved]]) - LAMP_PRIOR) <= BORDERLINE):
            return model, judgement  # only coin flips moved: the model judged is the refit of an equally good set
        lamp, judged = new, nd
        model.history_estimate = None  # judged: freed before the refit's estimate of every frame
        rows = np.flatnonzero(~new)
        model = fit_once(day, estimate=obs, rows=rows)
    return model, None


class _JointObjective:
    """−2 log posterior of the joint model over a history's frames, with the reflectances eliminated (their exact
    conditional mean), as a function of every frame's ``θ = (mired, δ, log k)``. Each frame's additive offset
    (veiling glare, :data:`illumon.camera.formation.FLARE_SD`) is eliminated with them, as the per-frame solver
    integrates it out."""

    def __init__(self, y: NDArray[np.float64], present: NDArray[np.bool_], css: NDArray[np.float64], dm: CIEDaylight,
                 rb: ReflectanceBasis, relative_error: float, absolute_error: float,
                 extra_var: NDArray[np.float64] | None = None, white: float = np.inf) -> None:
        self.dm = dm
        self.yz = np.where(present[..., None], y, 0.0)
        self.extra_var = None if extra_var is None else np.where(present[..., None], extra_var, 0.0)
        self.white = float(white)
        var = (relative_error * self.yz) ** 2 + absolute_error**2 + (0.0 if extra_var is None else self.extra_var)
        w2 = np.where(present[..., None], 1.0 / var, 0.0)
        w2[censored(self.yz, absolute_error, white)] = 0.0  # at 0 after the black level, or near white
        self.w2 = w2
        self.flare = flare_scales(self.yz, w2 > 0, formation.FLARE_SD, absolute_error)  # F × 3, or None
        self.k_ops, self.w_ops = imaging_operators(css, dm.basis, rb)
        self.lam = np.linalg.inv(rb.prior_covariance)
        self.mu = rb.prior_mean
        self._weighted: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None  # _weighted(w2, yz), kept
        self._offset_kept: tuple | None = None  # (weighted, flare, _offset_sums of them)
        self._noisy: tuple | None = None  # (noise, _weights(noise)) of the last noise other than 1

    def operators(self, th: NDArray[np.float64]) -> NDArray[np.float64]:
        """Per-frame maps (F × 3 × K) from reflectance coefficients to camera values."""
        return self._operators(th)[0]

    def _operators(self, th: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """:meth:`operators` and each frame's weights ``β`` (F × nb) of the imaging operators ``K`` they combine
        (``am[f] = Σ_i β[f, i] K[i]`` to rounding): the exposure over the camera white times the daylight weights."""
        a = np.asarray(self.dm.weights(th[:, :2]))
        white_g = (a @ self.w_ops)[:, 1]
        m = np.einsum("fk,kcj->fcj", a, self.k_ops) / white_g[:, None, None]
        k = np.exp(th[:, 2])
        return k[:, None, None] * m, a * (k / white_g)[:, None]

    def _weights(self, noise: float) -> tuple[NDArray[np.float64], tuple[NDArray[np.float64], NDArray[np.float64]]]:
        """The values' precisions at ``noise`` and their :func:`_weighted` sums, kept for ``noise`` 1 (the
        alternation's ~190 evaluations share them, issue 29; ``x / 1.0`` is ``x``) and for the last other ``noise``
        (the measured noise level's evaluations: :meth:`common_shift_sd`'s nine share them and :meth:`_offsets`'
        sums of them)."""
        if noise != 1.0:
            if self._noisy is None or self._noisy[0] != noise:
                w2 = self.w2 / noise**2
                self._noisy = (noise, (w2, _weighted(w2, self.yz)))
            return self._noisy[1]
        if self._weighted is None:
            self._weighted = _weighted(self.w2, self.yz)
        return self.w2, self._weighted

    def reflectances(self, th: NDArray[np.float64], noise: float = 1.0) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Reflectance posterior means (P × K) and precisions (P × K × K) given ``θ``."""
        (am, beta), (w2, weighted) = self._operators(th), self._weights(noise)
        if self.flare is None:
            return _reflectance_posterior(am, self.yz, w2, self.lam, self.mu, weighted)
        _, coef, _, prec = self._offsets(beta, weighted)  # given the offsets, each patch's posterior: the same mean
        return coef, prec

    def residuals(self, th: NDArray[np.float64], coef: NDArray[np.float64]) -> NDArray[np.float64]:
        """Every value's residual (F × P × 3) given ``θ`` and reflectances ``coef``, each frame's offset (the best
        for them) taken out."""
        am = self.operators(th)
        r = self.yz - np.einsum("fcj,pj->fpc", am, coef)
        if self.flare is None:
            return r
        # each frame's offset given the reflectances: its weighted mean residual, shrunk by its prior
        off = (self.w2 * r).sum(axis=1) / (self.w2.sum(axis=1) + 1.0 / self.flare**2)
        return r - off[:, None, :]

    def _offset_sums(self, weighted: tuple[NDArray[np.float64], NDArray[np.float64]]
                     ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """What :meth:`_offsets` reads of the values' :func:`_weighted` sums and :attr:`flare`, neither of which
        changes with ``θ``: the amounts' precisions ``d`` and information ``r_o`` (F × 3), the precisions by channel
        (3 × P × F) and the same times ``u / √d`` (3 × P × F). Kept for the last ``weighted`` and ``flare`` (the
        alternation's evaluations share them; :meth:`learn_flare_sd` sets a new ``flare``)."""
        kept = self._offset_kept
        if kept is not None and kept[0] is weighted and kept[1] is self.flare:
            return kept[2]
        wt, wty = weighted  # P × (F·3)
        u = self.flare
        n_p, f = wt.shape[0], u.shape[0]
        d = u**2 * wt.sum(axis=0).reshape(f, 3) + 1.0
        r_o = u * wty.sum(axis=0).reshape(f, 3)
        w_c = np.ascontiguousarray(wt.reshape(n_p, f, 3).transpose(2, 0, 1))
        parts = (d, r_o, w_c, w_c * (u / np.sqrt(d)).T[:, None, :])
        self._offset_kept = (weighted, self.flare, parts)
        return parts

    def _offsets(self, beta: NDArray[np.float64], weighted: tuple[NDArray[np.float64], NDArray[np.float64]]
                 ) -> tuple[NDArray[np.float64], NDArray[np.float64], float, NDArray[np.float64]]:
        """Each frame's additive offset (F × 3, ``u ⊙ φ`` of :func:`~illumon.camera.formation.flare_scales`) and the
        reflectances (P × K) that minimise the objective jointly: the offsets' block (diagonal: one amount per frame
        and channel, meeting no other) eliminated first, leaving one dense system in the P·K reflectance coefficients
        (a system in the offsets would grow with the history; this one does not). Returns the offsets, the
        reflectances, the amounts' prior cost ``Σ φ²`` and every patch's own precision (P × K × K, the offsets
        held: :func:`_normal_equations`'), given the frames' operator weights ``β`` (F × nb, :meth:`_operators`) and
        the values' :func:`_weighted` sums.

        Every frame's map is ``Σ_i β[f, i] K[i]`` over the ``nb`` (3) daylight basis operators, so the sums over the
        frames are taken on the ``nb``-dimensional weights and carried through ``K`` after: the offsets' coupling of
        patches ``p, q`` in channel ``c`` is ``K_cᵀ T_c[p, q] K_c`` with ``T_c = X_c X_cᵀ``, ``X_c[(p, i), f] =
        w[p, f, c] u[f, c] β[f, i] / √d[f, c]``, and the system, symmetric positive definite, is solved by Cholesky
        (three products of (P·nb) × F instead of one of (P·K) × F·3: with the solve ~3 × faster than the dense
        system of every frame's operator; the same system and solution to rounding, ~1e-12 relative)."""
        f, nb = beta.shape
        kc = self.k_ops.transpose(1, 0, 2)  # 3 (c) × nb × K
        k = kc.shape[2]
        u = self.flare
        wt, wty = weighted  # P × (F·3)
        n_p = wt.shape[0]
        d, r_o, w_c, x_c = self._offset_sums(weighted)
        # every patch's precision: Σ_c K_cᵀ (Σ_f w β βᵀ) K_c + Λ
        wbb = (w_c.reshape(3 * n_p, f) @ (beta[:, :, None] * beta[:, None, :]).reshape(f, nb * nb))
        prec = (kc.transpose(0, 2, 1)[:, None] @ (wbb.reshape(3, n_p, nb, nb) @ kc[:, None])).sum(axis=0) + self.lam
        # information with the amounts eliminated: Σ_{f,c} (w ȳ − w u r_o / d) (β_f K_c) + Λ μ
        h = wty.reshape(n_p, f, 3) - wt.reshape(n_p, f, 3) * (u * r_o / d)
        hb = (h.transpose(2, 0, 1).reshape(3 * n_p, f) @ beta).reshape(3, n_p, nb)
        rhs = hb.transpose(1, 0, 2).reshape(n_p, 3 * nb) @ kc.reshape(3 * nb, k) + self.lam @ self.mu
        # the amounts' coupling of the patches, − Σ_c (I ⊗ K_c)ᵀ X_c X_cᵀ (I ⊗ K_c)
        x = (x_c[:, :, None, :] * np.ascontiguousarray(beta.T)).reshape(3, n_p * nb, f)
        t = np.stack([xc @ xc.T for xc in x])  # 3 × (P·nb) × (P·nb); one product each (symmetric: half the work)
        t = (t.reshape(3, n_p * nb * n_p, nb) @ kc).reshape(3, n_p, nb, n_p, k)  # c, p, i, q, l
        t = t.transpose(1, 3, 4, 0, 2).reshape(n_p * n_p * k, 3 * nb) @ kc.reshape(3 * nb, k)  # (p, q, l), j
        system = -t.reshape(n_p, n_p, k, k).transpose(0, 3, 1, 2).reshape(n_p * k, n_p * k)
        idx = np.arange(n_p)[:, None] * k + np.arange(k)
        system[idx[:, :, None], idx[:, None, :]] += prec
        _, coef, info = dposv(system, rhs.reshape(-1))
        if info != 0:  # not positive definite to rounding: LU (which raises for a singular one)
            coef = np.linalg.solve(system, rhs.reshape(-1))
        coef = coef.reshape(n_p, k)
        # each amount given the reflectances: (r_o − u Σ_p w ŷ) / d, ŷ the patches' predicted values
        pred = ((self.k_ops.reshape(nb * 3, k) @ coef.T).reshape(nb, 3 * n_p).T @ beta.T).reshape(3, n_p, f)
        phi = (r_o - u * (w_c * pred).sum(axis=1).T) / d
        return u * phi, coef, float((phi**2).sum()), prec

    def learn_flare_sd(self, th: NDArray[np.float64], noise: float, flare_sd: float,
                       bounds: tuple[float, float] = (0.0, 0.12), strength: float = 30.0,
                       iterations: int = 30) -> float:
        """The history's own spread of its frames' offsets, learned from the frames with ``flare_sd`` as its prior:
        the maximum a posteriori spread by expectation–maximisation with ``θ`` held.

        Each offset ``o = s · m · φ`` (``m`` the frame's mean value in the channel,
        :func:`~illumon.camera.formation.flare_scales`) has posterior mean ``φ̄`` and variance ≈ ``1 / d`` (its own
        block; the coupling with the reflectances left out), and ``s²`` has a scaled inverse-χ² prior of
        ``strength`` degrees of freedom at ``flare_sd²``: ``s² ← (strength · flare_sd² + s² Σ (φ̄² + 1/d)) /
        (strength + 3 (F − 1))`` — the history's mean offset is its patches' (learned into their reflectances), so
        ``F`` frames tell ``3 (F − 1)`` amounts. A few frames keep about the prior's spread; a long history without
        glare brings it down (to ``bounds[0]`` at least), one with more glare up (to ``bounds[1]`` at most: 0.12,
        the root mean square of the offsets measured on the development photographs, ``benchmarks/flare.py``).
        Sets :attr:`flare` to the learned scales and returns ``s``."""
        if self.flare is None or flare_sd <= 0:
            return 0.0
        unit = self.flare / flare_sd
        (_, beta), (w2, weighted) = self._operators(th), self._weights(noise)
        sd, w_sum = flare_sd, w2.sum(axis=1)
        told = 3 * max(unit.shape[0] - 1, 0)
        for _ in range(iterations):
            self.flare = unit * sd
            off, _, _, _ = self._offsets(beta, weighted)
            seen = float(np.sum((off / self.flare) ** 2 + 1.0 / (self.flare**2 * w_sum + 1.0))) * sd**2
            new = float(np.clip(math.sqrt((strength * flare_sd**2 + seen) / (strength + told)), *bounds))
            done = abs(new - sd) <= 1e-3 * flare_sd
            sd = new
            if done:
                break
        self.flare = unit * sd
        return sd

    def __call__(self, th: NDArray[np.float64], noise: float = 1.0) -> tuple[float, NDArray[np.float64]]:
        return self.cost(*self._operators(th), th, noise)

    def costs(self, thetas: list[NDArray[np.float64]]) -> list[tuple[float, NDArray[np.float64]]]:
        """``self(th)`` of several ``θ`` of every frame, their operators from one evaluation of the daylight weights."""
        am, beta = self._operators(np.concatenate(thetas))
        am = am.reshape(len(thetas), *thetas[0].shape[:1], 3, -1)
        beta = beta.reshape(len(thetas), *thetas[0].shape[:1], -1)
        return [self.cost(a, b, th) for a, b, th in zip(am, beta, thetas, strict=True)]

    def cost(self, am: NDArray[np.float64], beta: NDArray[np.float64], th: NDArray[np.float64], noise: float = 1.0
             ) -> tuple[float, NDArray[np.float64]]:
        """``self(th)`` given its operators ``am`` and their weights ``beta`` (:meth:`_operators`)."""
        w2, weighted = self._weights(noise)
        if self.flare is None:
            y, prior = self.yz, 0.0
            s, _ = _reflectance_posterior(am, y, w2, self.lam, self.mu, weighted)
        else:
            off, s, prior, _ = self._offsets(beta, weighted)
            y = self.yz - off[:, None, :]
        r = y - (am.reshape(-1, am.shape[2]) @ s.T).reshape(am.shape[0], 3, -1).transpose(0, 2, 1)
        d = s - self.mu
        c = (w2 * r**2).sum() + ((d @ self.lam) * d).sum()
        c += prior
        c += self.dm.history_prior_cost(th[:, :2])
        return float(c), s

    def start(self, mired0: NDArray[np.float64], y: NDArray[np.float64], present: NDArray[np.bool_]) -> NDArray[np.float64]:
        """Gray-world temperatures on the locus, exposures from the frames' levels (each frame's mean green over
        its patches, 1 without any)."""
        zero = np.zeros_like(mired0)
        typical = np.einsum("fcj,j->fc", self.operators(np.stack([mired0, zero, zero], 1)), self.mu)
        return np.stack([mired0, zero, np.log(np.maximum(_mean_green(y, present), 1e-6)
                                              / np.maximum(typical[:, 1], 1e-9))], 1)

    def common_shift_sd(self, theta: NDArray[np.float64], noise: float) -> NDArray[np.float64]:
        """Laplace standard deviations of a shift common to every frame (reciprocal temperature, Duv offset): the
        direction static patches determine worst (profile curvature, reflectances re-solved; −2 log p → 2 H⁻¹)."""
        steps = np.array([1.0, 3e-4])
        c0 = self(theta, noise)[0]

        def shifted(i: int, si: float, j: int, sj: float) -> float:
            d = np.zeros(3)
            d[i] += si * steps[i]
            d[j] += sj * steps[j]
            return self(theta + d, noise)[0]

        hc = np.empty((2, 2))
        hc[0, 0] = (shifted(0, 1, 1, 0) - 2 * c0 + shifted(0, -1, 1, 0)) / steps[0] ** 2
        hc[1, 1] = (shifted(1, 1, 0, 0) - 2 * c0 + shifted(1, -1, 0, 0)) / steps[1] ** 2
        hc[0, 1] = hc[1, 0] = (shifted(0, 1, 1, 1) - shifted(0, 1, 1, -1) - shifted(0, -1, 1, 1)
                               + shifted(0, -1, 1, -1)) / (4 * steps[0] * steps[1])
        try:
            return np.sqrt(np.clip(np.diag(2 * np.linalg.inv(hc)), 0, None))
        except np.linalg.LinAlgError:
            return np.array([self.dm.mired_sigma, self.dm.duv_sigma])


CHART_LIGHT_MODEL_SD = 10.0
"""Standard deviation (MK⁻¹) added in quadrature to a chart's reading of its frame's light
(:mod:`illumon.camera.chart_light`): how far the camera prior, the CIE daylight model and the chart's own values leave
it off beyond its likelihood's spread."""

def _reference_level(objective: _JointObjective, theta: NDArray[np.float64], coef: NDArray[np.float64],
                     solver_args: tuple, y: NDArray[np.float64], present: NDArray[np.bool_],
                     extra: NDArray[np.float64] | None,
                     reference_light: tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]],
                     noise: float) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], dict]:
    """The shift common to every frame's reciprocal temperature from the charts' readings of their frames' light.

    The scene says its chart frames' temperatures up to the common shift (``common_shift_sd``, with the model's
    ``common_mired``); each chart says its frame's own (± its spread and :data:`CHART_LIGHT_MODEL_SD`). Two
    hypotheses weigh the charts' mean difference ``d``: the scene's level holds (``d ~ N(0, σ_c² + σ_s²)``: the two
    are combined by their precisions) or it was bent by frames no daylight explains (``d ~ N(0, σ_c² + σ_D²)``,
    ``σ_D`` the daylight prior's spread, probability :data:`~illumon.camera.calibration.BENT_PRIOR`: the charts'
    reading is taken), by :func:`~illumon.camera.calibration.held_or_bent`: the more probable one is kept, its
    standard deviation the mixture's about that mean. Every frame's ``(mired)`` moves by the shift and the reflectances
    are re-solved at it. ``y``, ``present``, ``extra``: the chart frames' rows of the history on the fit's scale
    (their scene patches are estimated with the fitted reflectances). Returns ``θ``, the coefficients, the common
    shift's standard deviation (mired, Duv: ``inf``, not constrained) and a summary for ``model.noise``."""
    css, dm, rb, rel, absolute = solver_args
    frames, mired, sd = reference_light
    solver = FrameSolver(css, coef, None, dm, rb, relative_error=rel, absolute_error=absolute, white=objective.white)
    scene = solver.solve_theta(y, present, extra)[:, 0]
    var_c = sd**2 + CHART_LIGHT_MODEL_SD**2
    w = 1.0 / var_c
    d = float(np.sum(w * (mired - scene)) / np.sum(w))
    v_c = float(1.0 / np.sum(w))
    s_s = float(math.hypot(objective.common_shift_sd(theta, noise)[0], MODEL_ERROR["common_mired"]))
    shift, post_sd, bent = held_or_bent(d, v_c, s_s, float(dm.mired_sigma))
    lo_b, hi_b = dm.bounds()
    theta = theta.copy()
    theta[:, 0] = np.clip(theta[:, 0] + shift, lo_b[0], hi_b[0])
    coef, _ = objective.reflectances(theta)
    summary = {"frames": frames.tolist(), "chart_mired": mired.tolist(), "scene_mired": scene.tolist(),
               "shift_mired": shift, "bent": bent}
    return theta, coef, np.array([post_sd, np.inf]), summary


def _alternate(
    objective: _JointObjective, theta: NDArray[np.float64], solver_args: tuple, y: NDArray[np.float64],
    present: NDArray[np.bool_], iterations: int, tol: float,
) -> tuple[NDArray[np.float64], NDArray[np.float64], int]:
    """Block coordinate descent: reflectances given θ, then every frame's θ given the reflectances, with candidates
    along the over-relaxed step and common shifts of every frame's reciprocal temperature (the directions in which the
    alternation crawls; the common shift is only weakly determined). Returns θ, the coefficients and the iterations."""
    css, dm, rb, rel, absolute = solver_args
    best, coef = objective(theta)
    lo_b, hi_b = dm.bounds()
    n_iter = 0
    for n_iter in range(1, iterations + 1):  # noqa: B007
        new = FrameSolver(css, coef, None, dm, rb, relative_error=rel, absolute_error=absolute,
                          white=objective.white).solve_theta(y, present, objective.extra_var)
        cands = [theta + alpha * (new - theta) for alpha in (2.0, 4.0, 8.0)]
        cands += [new + np.array([shift, 0.0, 0.0]) for shift in (-16.0, -4.0, -1.0, 1.0, 4.0, 16.0)]
        for cand in cands:
            cand[:, 0] = np.clip(cand[:, 0], lo_b[0], hi_b[0])
            cand[:, 1] = np.clip(cand[:, 1], lo_b[1], hi_b[1])
        (c_new, s_new), *scored = objective.costs([new, *cands])
        prev = theta
        theta, best_new, coef = new, c_new, s_new
        for cand, (c_c, s_c) in zip(cands, scored, strict=True):
            if c_c < best_new:
                theta, best_new, coef = cand, c_c, s_c
        change = float(np.max(np.abs(theta[:, 0] - prev[:, 0])))
        improvement = best - best_new
        best = best_new
        if change < tol or improvement < 1e-6 * abs(best):
            break
    return theta, coef, n_iter


def _frame_costs(objective: _JointObjective, theta: NDArray[np.float64], coef: NDArray[np.float64]
                 ) -> NDArray[np.float64]:
    """Each frame's misfit in the joint fit: its weighted squared residuals (its offset out, the nominal noise
    model's weights) per value it weighs."""
    r2 = objective.w2 * objective.residuals(theta, coef) ** 2
    return r2.sum(axis=(1, 2)) / np.maximum((objective.w2 > 0).sum(axis=(1, 2)), 1)


def _frames_explained(costs: NDArray[np.float64], present: NDArray[np.bool_]) -> NDArray[np.bool_] | None:
    """The frames to learn the reflectances from, or ``None`` to keep them all: frames no daylight explains left out,
    given each frame's misfit ``costs`` (:func:`_frame_costs`) and its patches ``present``.

    Issue 26, a light booth: a fluorescent frame (FL2, FL11) in a history the joint fit explains with daylight is
    explained by bending the static patches' shared reflectances, and that moves the common temperature of every
    frame (``benchmarks/lightbox.py``: a D65 simulator read as 23 285 K, every frame −111 MK⁻¹, the whites right).
    Such a frame's misfit stands out (:func:`_frame_costs`: 4.4–5.8 against 0.6–0.8 for the D65 frames in the
    booth's first fit), and once it is left out the other frames' misfit falls several-fold (the kept frames' median
    2.4–230 × lower, median 4.0: the reflectances no longer bent). A frame is a candidate when its misfit exceeds
    :data:`FRAME_COST_RATIO` × the history's median frame and :data:`FRAME_COST_FLOOR`; :func:`_fit_fixed_camera`
    refits without the candidates and keeps that refit only if the kept frames' median misfit fell by
    :data:`FRAME_REFIT_GAIN` or more. Daylight histories have frames as badly fitted (the development split of
    ``benchmarks/unmeasured.py``, one seed: a candidate in 47 of 817 fits, with glare 117 of 833), but leaving them
    out hardly helps the rest (median misfit 0.8–2.9 × lower) and was worse there (ratio 3, no such test: rawsim's
    rendered median 1.40° → 4.11°); the test keeps every one of them
    (every daylight history's estimates unchanged, bit for bit). None is left out when fewer than half the frames, or
    not every patch, would remain — so a history lit mostly by lamps (the whole booth: its median frame a lamp's) is
    not helped; every frame is still estimated by the per-frame solver afterwards."""
    out = costs > max(FRAME_COST_RATIO * float(np.median(costs)), FRAME_COST_FLOOR)
    if not out.any() or (~out).sum() < max(2, 0.5 * len(out)) or not np.all(present[~out].any(axis=0)):
        return None
    return ~out


def _training_summary(obs: Observations, present_all: NDArray[np.bool_], n_sub: int, cct: NDArray[np.float64],
                      n_iter: int, seconds: float) -> dict:
    """``cct``: the estimates of ``obs``'s frames."""
    mired_all = 1e6 / cct
    ok = np.isfinite(mired_all)
    times = [t for t in obs.times if t]
    return {
        "frames": len(obs.frames),
        "frames_used_for_reflectances": int(n_sub),
        "patches": len(obs.patches),
        "observed_fraction": float(present_all.mean()),
        "time_first": min(times) if times else "",
        "time_last": max(times) if times else "",
        "mired_min": float(np.min(mired_all[ok])),
        "mired_max": float(np.max(mired_all[ok])),
        "mired_std": float(np.std(mired_all[ok])),
        "cct_p05": float(np.percentile(cct[ok], 5)),
        "cct_p95": float(np.percentile(cct[ok], 95)),
        "iterations": n_iter,
        "fit_seconds": round(seconds, 3),
    }


@single_blas_thread
def _fit_fixed_camera(
    obs: Observations,
    sensitivities: NDArray[np.float64],
    *,
    daylight: CIEDaylight | None = None,
    relative_error: float = 0.02,
    absolute_error: float = 0.002,
    max_fit_frames: int = 300,
    iterations: int = 40,
    tol: float = 0.01,
    balance_sd: float | None = None,
    camera_level: tuple[NDArray[np.float64], float, bool] | None = None,
    estimate: Observations | None = None,
    rows: NDArray[np.intp] | None = None,
    reference_light: tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]] | None = None,
    common_level: tuple[float, float, float, float] | None = None,
) -> tuple[SceneModel, NDArray[np.float64]]:
    """:func:`fit_scene_model` for given (effective) sensitivities. Returns the model and every frame's
    ``(mired, δ, log k)`` (F × 3) from the learned reflectances. ``balance_sd``: the output is white-balanced by the
    camera, the history's mean white lies within that spread (log r/g, b/g) of grey — for daylight; a history lit
    only by lamps is told apart by its scene average (:mod:`.level`). ``camera_level``: sensor RGB, ``(sensitivities
    the daylight and lamp whites are taken through, spread of their white, measured)`` — the prior camera and the
    measured cameras' spread for a camera nobody measured, the camera itself and :data:`MEASURED_WHITE_SD` for a
    measured one; a history the scene average places among the lamps' whites through that camera rather than the
    daylights' is anchored there as a lamp-lit one (:mod:`.level`); a daylight one keeps the fit's level, a measured
    camera's joined by the scene average where that is the better evidence (:func:`.level.daylight_level`).

    ``estimate``: the frames ``model.history_estimate`` (and the returned ``θ``) holds, a history whose frames
    ``rows`` are ``obs`` (the same patches; the training summary and identifiability read those rows); default
    ``obs``. Every frame is estimated on its own, so the rows equal an estimate of ``obs`` alone.

    ``reference_light``: frames of ``obs`` that showed a chart, and the chart's reading of their light (reciprocal
    temperature and its standard deviation, :mod:`illumon.camera.chart_light`): evidence on the shift common to every
    frame that the static patches cannot see, taken by :func:`_reference_level`.

    ``common_level``: ``(mired, δ, common_mired, common_duv)``, the history's median light held there (instead of
    ``balance_sd``'s anchor) and the model errors of that common level (``model_error``'s, as the fit that set it
    stated them): a rendered camera's reference iterations (:func:`illumon.camera.calibration.calibrate_scene_model`)
    refine ``T`` at a level they hold (:func:`illumon.camera.calibration._held_level`)."""
    t0 = time.perf_counter()
    dm = daylight or CIEDaylight()
    rb = reflectance_basis()
    css = np.asarray(sensitivities, dtype=float)
    y_all = np.asarray(obs.values, dtype=float)
    if y_all.shape[0] < 1:
        raise ValueError("fitting a scene model needs at least one frame")
    present_all = observed(y_all)
    if present_all.any(axis=0).sum() < 2:
        raise ValueError("fitting a scene model needs at least two patches")
    unseen = [p for p, s in zip(obs.patches, present_all.any(axis=0), strict=True) if not s]
    if unseen:
        raise ValueError(f"patch(es) never observed: {', '.join(unseen)}")
    green = y_all[..., 1][present_all]
    scale = float(np.median(green)) if green.size else 1.0
    if not scale > 0:
        raise ValueError("observations are all black (median green is 0)")
    gw_mired = grey_world_mired(obs, css)
    sub = spread_subsample(gw_mired, max_fit_frames)
    y = y_all[sub] / scale
    present = present_all[sub]
    extra = None if obs.sd is None else obs.extra_variance()[sub] / scale**2  # measured noise (Observations.sd)
    white = white_level(y_all)
    objective = _JointObjective(y, present, css, dm, rb, relative_error, absolute_error, extra, white / scale)
    theta = objective.start(gw_mired[sub], y, present)
    theta, coef, n_iter = _alternate(objective, theta, (css, dm, rb, relative_error, absolute_error), y, present,
                                     iterations, tol)
    for _ in range(ROBUST_ROUNDS):  # frames no daylight explains, left out of the reflectances (_frames_explained)
        costs = _frame_costs(objective, theta, coef)
        keep = _frames_explained(costs, present)
        if keep is None:
            break
        k_extra = None if extra is None else extra[keep]
        k_obj = _JointObjective(y[keep], present[keep], css, dm, rb, relative_error, absolute_error, k_extra,
                                white / scale)
        k_theta, k_coef, k_iter = _alternate(k_obj, theta[keep], (css, dm, rb, relative_error, absolute_error),
                                             y[keep], present[keep], iterations, tol)
        if float(np.median(_frame_costs(k_obj, k_theta, k_coef))) * FRAME_REFIT_GAIN > float(np.median(costs[keep])):
            break  # the kept frames fit (about) as well with them: not frames that bent the reflectances
        sub, y, present, extra = sub[keep], y[keep], present[keep], k_extra
        objective, theta, coef, n_iter = k_obj, k_theta, k_coef, k_iter

    def measured_noise() -> float:
        """The history's noise level: the fit's residuals (each frame's offset out) over their degrees of freedom."""
        resid2 = objective.w2 * objective.residuals(theta, coef) ** 2
        n_offsets = 0 if objective.flare is None else 3 * len(sub)
        dof = max(int(present.sum()) * 3 - 3 * len(sub) - n_offsets - rb.size * len(obs.patches), 1)
        return float(max(math.sqrt(resid2.sum() / dof), 0.5))

    # the history's own glare spread (FLARE_SD is its prior), at the measured noise level, for the reflectances'
    # posterior and the per-frame solver. The frames' light is not fitted again with it: on a real lamp-lit scene
    # (MIMO `lion`, six frames) that sent the white from 1.9° to 29.6°, and it moved the closed loop's glare-free day
    # by 0.02°.
    flare_sd = objective.learn_flare_sd(theta, measured_noise(), formation.FLARE_SD, (FLARE_SD_MIN, FLARE_SD_MAX))
    anchored_sd, level = None, None
    pins_mired = True
    if reference_light is not None:
        chart = reference_light[0]  # the chart frames: their rows only, not a copy of the whole history
        theta, coef, anchored_sd, chart_level = _reference_level(
            objective, theta, coef, (css, dm, rb, relative_error, absolute_error), y_all[chart] / scale,
            present_all[chart], None if obs.sd is None else sd_variance(obs.sd[chart]) / scale**2, reference_light,
            measured_noise())
    verdict = (0.0, 0.0)  # the lamp-lit-or-balanced verdict's other reading of the light's temperature (shift, p)
    if common_level is not None:
        lo_b, hi_b = dm.bounds()
        held = np.array(common_level[:2]) - np.median(theta[:, :2], axis=0)
        theta = theta.copy()
        theta[:, :2] = np.clip(theta[:, :2] + held, lo_b, hi_b)
        coef, _ = objective.reflectances(theta)
    elif balance_sd is not None or camera_level is not None:
        # the level static patches cannot see (:mod:`.level`): a rendered camera's balance, or sensor RGB's daylight
        # through the camera, against the scene average; the lamp-lit component's mixed lamps are half the prior's
        # mean daylight (chosen so on the MIMO scenes)
        # the observations' output space: a balance anchor is rendered output's (fit_scene_model gives it for srgb)
        average = scene_average_evidence(y, present, "srgb" if balance_sd is not None else "camera")
        fit_level = mean_log_chroma(dm, css, theta)
        reading = scene_reading(dm, css, theta, average, rb)
        if balance_sd is not None:
            level = common_level_posterior(fit_level, SCENE_AVERAGE_SD, balance_sd, average, reading,
                                           lamp_population(css, dm, 1)[2])
        else:
            base, camera_sd, measured = camera_level
            days, days_logw, lamps, _ = lamp_population(base, dm, 1)
            level = posterior = common_level_posterior(fit_level, SCENE_AVERAGE_SD, camera_sd, average, reading,
                                                       lamps, balanced=(days, days_logw), camera_sd=camera_sd)
            if level.unbalanced <= 0.5:
                # daylight: an unmeasured camera keeps the prior camera's level (the calibration's scene-average
                # transform); a measured one the fit's, joined by the scene average where that is the better evidence
                # a camera nobody measured over a few frames (FEW_FRAMES_LEVEL) too: there the fit's level is the
                # reflectance prior's guess alone (FEW_FRAMES_FIT_LEVEL_SD), and a pale scene's reading the better evidence
                regime = history_length_regime(len(obs.frames))
                level = (daylight_level(fit_level, FIT_LEVEL_SD if measured else FEW_FRAMES_FIT_LEVEL_SD[regime],
                                        average, reading, level.unbalanced)
                         if measured or regime <= FEW_FRAMES_LEVEL else None)
                pins_mired = measured  # a camera nobody measured: the scene pins its white, not the temperature
            # sensor RGB's verdict (not a balance's: rendered output's was right on every development history, lamp-lit
            # or not) was wrong on 5 of 14 lamp-only ones, so its other reading joins the temperature's interval
            verdict = verdict_shift(dm, css, theta, fit_level if level is None else level.mean, posterior)
        if level is not None:
            theta, coef, anchored_sd = anchor_common_level(objective, theta, css, level)
    noise_scale = measured_noise()
    # Posterior with the measured noise level (β scaled by 1/noise_scale²).
    coef, prec = objective.reflectances(theta, noise_scale)
    cov = np.linalg.inv(prec)
    cov = 0.5 * (cov + cov.transpose(0, 2, 1))
    common = objective.common_shift_sd(theta, noise_scale)
    if reference_light is not None:  # the charts' combination with the scene (or their reading alone) holds it
        common = np.array([anchored_sd[0], common[1]])
    elif anchored_sd is not None and pins_mired:
        # the common level is the anchored posterior's, not the reflectance prior's — where it reads the light's
        # temperature: for a camera nobody measured (FEW_FRAMES_LEVEL) the unknown channel scales stand between
        common = np.minimum(common, anchored_sd)
    model = SceneModel(
        patches=list(obs.patches), coefficients=coef, covariance=cov, sensitivities=css,
        grid=(float(GRID.start), float(GRID.end), float(GRID.interval)), basis=rb.functions,
        daylight={"name": "cie", "duv_sigma": dm.duv_sigma, "mired_mean": dm.mired_mean, "mired_sigma": dm.mired_sigma},
        noise={"relative_error": relative_error, "absolute_error": absolute_error, "noise_scale": noise_scale,
               "scale": scale, "white_level": white if math.isfinite(white) else None, "flare_sd": flare_sd,
               "model_error": dict(MODEL_ERROR, common_mired=float(math.hypot(common[0], MODEL_ERROR["common_mired"])),
                                   common_duv=float(max(common[1], MODEL_ERROR["common_duv"])),
                                   **(dict(zip(VERDICT_KEYS, verdict, strict=True)) if verdict[1] > 0 else {}))},
    )
    if common_level is not None:  # the level held is an earlier fit's, as uncertain as that fit stated it
        model.noise["model_error"].update(common_mired=float(common_level[2]), common_duv=float(common_level[3]))
    if level is not None and level.unbalanced > 0.5:  # lamps only: the level the scene average gave, for the verdicts
        model.noise.update(unbalanced=level.unbalanced, level=level.mean.tolist(), level_sd=level.sd)
    if reference_light is not None:
        model.noise["chart_level"] = chart_level
    # Illuminants of every frame with the learned reflectances (the fast solver), for the training summary.
    res, extra = model.estimate(obs if estimate is None else estimate)
    model.history_estimate = (res, extra)
    model.fit_frames = sub if estimate is None else np.asarray(rows)[sub]
    cct = res.cct if estimate is None else res.cct[rows]
    model.training = _training_summary(obs, present_all, len(sub), cct, n_iter, time.perf_counter() - t0)
    mired_all = 1e6 / cct
    model.identifiability = identifiability(
        y, present, css, dm, rb, theta, coef, objective.w2 / noise_scale**2, mired_all[np.isfinite(mired_all)],
        flare=objective.flare,
    )
    if reference_light is not None and chart_level["bent"] > 0.5:
        model.identifiability["warnings"].append(
            f"the scene's light disagrees with the chart's ({chart_level['shift_mired']:+.0f} MK⁻¹ in the chart's "
            "frame): frames lit by lamps, not daylight, bent the patches' shared colours; every frame's temperature "
            "was taken from the chart")
    for msg in model.identifiability["warnings"]:
        warnings.warn(msg, IdentifiabilityWarning, stacklevel=3)
    return model, res.info["theta"]
