"""Cameras nobody measured: a prior from the measured cameras, refined by references of known reflectance.

The camera's output channels are modelled as ``C_eff = C0 T``: ``C0`` are sensitivities known up to a 3 × 3 transform —
the mean of the measured cameras for a camera nobody measured (:func:`prior_sensitivities`), or measured raw
sensitivities — and ``T`` absorbs the rest: how this camera's channels differ from the mean ones and any fixed colour
matrix the camera applies (a matrix ``M`` turns ``C`` into ``C Mᵀ``). Everything illumon estimates is then in the
space of the observations themselves, the space the camera's own white-balance gains act in.

``T`` is estimated jointly with the scene by block coordinate descent on the joint posterior (Y. Kinoshita & H. Kiya,
"Bayesian spectral estimation": the sensitivity given illuminants and reflectances is linear with a Gaussian posterior,
their eqs. 15–16, here in the 3-dimensional basis spanned by ``C0``'s columns, :func:`illumon.bayes.gaussian_posterior`):

1. fit the scene (every frame's daylight and exposure, every patch's reflectance) with the current ``C0 T``, references
   entering with their exact spectra;
2. given the frames' daylight, the references' camera values are linear in ``T``: each output channel's row of ``T``
   has a Gaussian posterior; a frame's unknown exposure is eliminated by alternation;
3. repeat until the camera white moves by less than 0.01°.

What a reference pins: a grey card (flat) only each channel's scale (``T`` diagonal); a chart with chromatic patches
the whole 3 × 3 ``T``. Without references, rendered output keeps ``T`` at its prior mean (the identity: the camera's
own balance set its scales), and sensor RGB reads ``T``'s diagonal from the scene's average colour
(:func:`_scene_average_transform`, gray-world made Bayesian) at the fitted light, read again at each refit's light
until the camera white moves by less than ``tol_deg`` — unless the history was judged lit by lamps throughout
(:mod:`illumon.model.level`), whose colour is the lamps' and is read once. The scene cannot say how its colour splits
between the channel scales and the light: the move of the light's temperature from the first fit (through the prior
camera) to the last widens the temperature's interval (``noise["split_mired"]``). The estimate carries the spread of
the measured cameras as an extra, honest uncertainty (:data:`CAMERA_WHITE_SD`).

References
----------
.. [Kinoshita2023] Kinoshita & Kiya, 2023: eqs. 15–16, the sensitivity posterior.
.. [Finlayson1997] Finlayson & Drew, CIC 1997: white-point preservation.
.. [Buchsbaum1980] Buchsbaum, 1980: grey world.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numpy.typing import NDArray

from ..bayes import GaussianPrior, gaussian_posterior
from ..daylight import CIEDaylight
from ..observations import Observations
from ..priors import CameraPrior, default_camera_prior, rendered_camera_prior
from ..priors.scene_average import expected_offset, log_chroma, scene_average_evidence
from .chart_light import chart_light_illumon
from .formation import Z95, angular_error_deg, flare_scales, within_one_degree
from .references import neutral_references, references_kind

__all__ = ["BENT_PRIOR", "CAMERA_MIRED_SD", "CAMERA_WHITE_SD", "PRESET_MIRED_SD", "SINGLE_FRAME_MIRED_SD",
           "SINGLE_FRAME_WHITE_SPREAD", "SHORT_HISTORY_MIRED_SD", "SHORT_HISTORY_WHITE_SPREAD",
           "STATED_WHITE_SPREAD", "HISTORY_LENGTHS", "history_length_regime",
           "CameraCalibration", "prior_sensitivities", "camera_transform_Kinoshita2023", "calibrate_scene_model",
           "held_or_bent"]

CAMERA_WHITE_SD = {"measured": 0.0, "grey": 0.005, "chart": 0.015, "none": 0.11}
"""Standard deviation (log units per chromatic channel, r/g and b/g) of the camera white that the camera model itself
leaves uncertain, added to every estimate's intervals and confidence. ``none``: the spread of the measured cameras'
daylight whites around the mean camera's (see :func:`prior_white_spread`); ``grey`` and ``chart``: what a reference
leaves, measured on development cameras (``python benchmarks/unmeasured.py``)."""

CAMERA_MIRED_SD = {"measured": 0.0, "chart": 13.0, "chart read": 0.0, "chart read as srgb": 4.0, "grey": 21.0,
                   "none": 12.0}
"""Standard deviation (MK⁻¹) of the light's reciprocal temperature that an unmeasured camera leaves uncertain, added
to the CCT intervals (not to the white's: a reference pins the white, not the temperature — a redder camera under bluer
light shows the same chart). Chosen on the development cameras (``python tools/camera_mired_spread.py --seeds 2``:
CIE D65 in frame 0, Granada runs after it, the prior without the camera's maker): the RMS mired error over all frames
was 16.0 (chart), 22.9 (grey card) and 14.8 (none) against a stated 8.3, 95 % intervals held 82 %, 78 % and 85 % of
the truths; these are the values that bring the z-scores' RMS to 1. A grey card pins the camera's channel scales
under one light, which the history's static patches cannot tell from a shift of every frame's temperature: its CCT is
the least certain of the three. ``chart read``: a chart whose frame's light was read with the camera integrated out
(:mod:`.chart_light`, combined with the scene's in :func:`illumon.model.fit._reference_level`), whose spread the
intervals then carry already: RMS mired error over all frames 7.2 against a stated 16.9 with 13 added (z RMS 0.42,
``--seeds 1``) and 14.0 with nothing added (z RMS 0.52), so nothing is added. ``chart read as srgb``: a camera
declared sensor RGB whose chart only the rendered cameras' prior explains (:func:`_chart_readings`): development
cameras through their colour matrix (``python tools/camera_mired_spread.py --matrix --cases chart --seeds 2``), RMS
mired error over all frames 13.1 against a stated 11.7 (z RMS 1.05): 4.0 brings it to 1. Rendered (``srgb``)
output: see :data:`SRGB_CAMERA_MIRED_SD`."""

SRGB_CAMERA_MIRED_SD = {"measured": 0.0, "chart": 6.5, "grey": 6.0, "none": 3.5}
"""As :data:`CAMERA_MIRED_SD` for rendered (``srgb``) output, where the temperature is read with the sRGB functions
before the reference moves the camera (``mired_offset`` in :func:`calibrate_scene_model`). Development cameras
rendered through their white-preserving matrix to sRGB (``python tools/camera_mired_spread.py --seeds 2 --primaries
srgb``): RMS mired error over all frames 10.3 (chart), 10.4 (grey card), 9.4 (none) against a stated 8.1–8.3 (before
the offset: 45.1 and 50.6 with a reference)."""


SRGB_CAMERA_WHITE_SD = 0.018
"""For rendered (``srgb``) output with no reference or a grey card (which pins only channel scales): how far a real
camera's white, carried to sRGB primaries by its
white-preserving matrix (:func:`illumon.camera.primaries.to_srgb_primaries`), departs from the sRGB colour-matching
functions' under daylight away from D65 — 0.0074–0.044 for the 24 measured cameras, pooled RMS 0.018 (log r/g, b/g;
every 7th Granada spectrum). The history's common level adds its own, larger uncertainty
(:func:`illumon.model.level.anchor_common_level`)."""

STATED_WHITE_SPREAD = {("camera", "grey"): (1.52, 0.0039, 0.6), ("camera", "chart"): (2.09, 0.0048, 0.6),
                       ("camera", "none"): (2.09, 0.0095, 0.0), ("srgb", "grey"): (2.449, 0.0024, 0.8),
                       ("srgb", "chart"): (1.521, 0.0072, 0.7), ("srgb", "none"): (0.805, 0.0038, 0.0)}
"""What a camera nobody measured states about its camera white, per ``(primaries, calibration)``: ``(a, s, k)`` —
the Laplace posterior's spread scaled by ``a`` (it leaves out how the camera, the priors and the scene depart from
the model) plus the camera's own spread ``s`` (log r/g, b/g) and ``k`` times what the reference frames' veiling glare
leaves uncertain in this history (:func:`_glare_white_sd`, from the glare spread the history learned) — in its gain
intervals and ``confidence``. Chosen on the development split with the glare offset on
(:data:`~illumon.camera.formation.FLARE_SD` 0.05), over histories with and without veiling glare pooled (``python
benchmarks/unmeasured.py --split dev --seeds 1 --out dev.json``, the same with ``--flare --out dev_flare.json``,
then ``python tools/confidence_calibration.py dev.json dev_flare.json``: 14 development cameras × 1 seed × both
simulators × with and without glare): among the triples with which the mean stated confidence equals the fraction
of frames within 1°, the one with the largest likelihood of which frames were. Before ``k`` (2026-11-26), a grey card
on sensor RGB stated 0.80 on the glare-free histories, where 90 % were within 1°, and 0.79 on the glared ones, where
65 % were; with it 0.90 and 0.74 (``illumon``; ``rawsim`` 0.93 where 100 %, 0.75 where 76 %). They replace, in the
intervals only, the physical spreads above — :data:`CAMERA_WHITE_SD` ``none`` (0.11) is the measured cameras'
spread *before* the scene's average colour moved the channel scales and stated 0.01 where 15 % of frames were
within 1°; a grey card's 0.005 stated 0.99 where 96 % were; a chart on rendered output (``chart+rendered``,
``chart+awb``) stated 0.46–0.49 where 25–38 % were. The priors, the lamp test and the estimates keep the physical
values (``camera["white_sd_log"]``); measured cameras and unlisted regimes keep theirs with ``a = k = 1``.
``("camera", "none")``: ``a`` is further scaled by :func:`scene_calibrated_scale` of the scene the channel scales
were read from (chosen on scenes of measured surfaces, for which the scale is 1). ``("srgb", "chart")`` was chosen
again (2026-11-27, the same commands, cases ``chart+rendered`` and ``chart+awb``) when a chart's reference iterations
stopped chasing ``T`` (:func:`_held_level`): with the former ``(1.30, 0.0187, 0.0)`` it stated 0.35 where 87 % of
``rawsim``'s glare-free rendered frames were within 1°. ``("srgb", "grey")`` was chosen again (2026-11-27, the same
commands, every other regime's triple reproduced) when a grey card's stopped chasing too: ``(2.09, 0.0144, 0.5)`` →
``(2.449, 0.0024, 0.8)``."""


SINGLE_FRAME_WHITE_SPREAD = {("camera", "none"): (0.5, 0.0289, 0.0), ("srgb", "none"): (1.521, 0.021, 0.0)}
""":data:`STATED_WHITE_SPREAD` of a scene model fitted on a single frame without a reference (one photograph, and the
later frames estimated with that model): one view cannot teach the scene, so the regimes chosen on 30-frame histories
said too much of rendered output (0.18 where 5 % of the development single frames were within 1°) and too little of
sensor RGB (0.03 where 12 % were). Chosen as they were, on single frames (``python benchmarks/unmeasured.py --split
dev --seeds 3 --frames 1 --out one.json``, then ``python tools/confidence_calibration.py one.json``: 14 development
cameras × 3 seeds × both simulators; ``a`` at the tool's least for sensor RGB). A reference frame states its own
spread (:data:`REFERENCE_WHITE_SD_DEG`), single or not."""


SINGLE_FRAME_MIRED_SD = {("camera", "none"): 33.0, ("srgb", "none"): 29.0, ("camera", "grey"): 48.5,
                         ("camera", "chart"): 67.4}
"""Reciprocal-temperature spread (MK⁻¹) added to the CCT intervals of a scene model fitted on a single frame, per
``(primaries, calibration)`` as :data:`CAMERA_MIRED_SD` keys them. Without a reference: the RMS error of the
development single frames' temperatures (``python benchmarks/unmeasured.py --split dev --seeds 3 --frames 1``: 32–35
and 28–30 MK⁻¹). One view does not show how the light moves, which pins a history's temperatures; the intervals held
the light's temperature in 90 % (sensor RGB), 79–86 % (sensor RGB over pale surfaces) and 62–64 % (rendered output)
of those frames, and hold it in 95–98 %, 90–93 % and 95 % with it. A reference's single frame on sensor RGB reads
its light worst of all (the card's white is the camera's and the light's at once): a grey card 59 MK⁻¹ RMS off, a
chart whose reading of the light was refused 72 (``chart``), one read as rendered 12 (``chart read as srgb``, which
its intervals already hold: nothing added); the spreads that bring their z-scores to an RMS of 1 (``python
benchmarks/unmeasured.py --split dev --seeds 2 --frames 1 --cases grey,chart+matrix``, the same with ``--flare``,
then ``tools/confidence_calibration.py``'s temperature table, by :func:`camera_mired_key`) are 48.5 and 67.4. Their
intervals often reach past infinite temperature — "warmer than this, no more is known" is what one frame of an
unmeasured camera tells."""


SHORT_HISTORY_WHITE_SPREAD: dict[int, dict[tuple[str, str], tuple[float, float, float]]] = {
    3: {("camera", "grey"): (0.5, 0.0077, 0.5), ("camera", "chart"): (0.635, 0.0043, 0.3),
        ("camera", "none"): (0.395, 0.024, 0.0), ("srgb", "grey"): (0.805, 0.0193, 0.4),
        ("srgb", "chart"): (0.462, 0.0076, 0.1), ("srgb", "none"): (0.541, 0.0256, 0.0)},
    6: {("camera", "grey"): (0.011, 0.0089, 0.3), ("camera", "chart"): (1.783, 0.0081, 0.0),
        ("camera", "none"): (0.872, 0.0316, 0.0), ("srgb", "grey"): (2.09, 0.0127, 0.3),
        ("srgb", "chart"): (1.783, 0.0084, 0.0), ("srgb", "none"): (1.198, 0.0087, 0.0)},
}
""":data:`STATED_WHITE_SPREAD` of a scene model fitted on a short history (2–13 frames, :func:`history_length_regime`:
the regimes chosen on 3 frames for 2–4, on 6 for 5–13), per ``(primaries, calibration)``. A short history has fewer
values than the scene has reflectance coefficients, so its noise level (the residuals over their clamped degrees of
freedom, :func:`illumon.model.fit._fit_fixed_camera`) reads 2–8 × a long history's and the Laplace part is too
wide: with the 30-frame regimes a grey card on sensor RGB stated 0.50 where 86 % of the development three-frame
histories' frames were within 1°, no reference 0.04 where 32 % were (``python benchmarks/unmeasured.py --split dev
--seeds 1 --frames 3``, both simulators; 0.69 and 0.18 with these). Chosen as the others were, on histories of that
length (``python benchmarks/unmeasured.py --split dev --seeds 2 --frames 3 --out c3.json``, the same with ``--flare
--out c3f.json``, then ``python tools/confidence_calibration.py c3.json c3f.json --scales-from 0.01``; ``--frames
6`` likewise): 14 development cameras × 2 seeds × both simulators × with and without glare. ``a`` below the
30-frame regimes' 0.5 floor where the clamped level inflates the Laplace part most; a grey card's six-frame ``a``
(0.011) leaves its statement to the camera's and the glare's spreads. The estimates do not change (the noise level
the fit uses is not touched: counting the degrees of freedom the priors leave took the real ``sony-raw`` set from
1.60 to 5.42°, docs/methods.md)."""

SHORT_HISTORY_MIRED_SD: dict[int, dict[tuple[str, str], float]] = {
    3: {("camera", "grey"): 39.5, ("camera", "chart"): 38.3},
    6: {("camera", "grey"): 38.8, ("camera", "chart"): 43.4, ("camera", "none"): 31.2},
}
"""Reciprocal-temperature spread (MK⁻¹) added to the CCT intervals of a scene model on sensor RGB fitted on a short
history (:func:`history_length_regime`), per ``(primaries, key)`` with :func:`camera_mired_key`'s keys: the spread
that brings the development frames' z-scores to an RMS of 1 (``tools/confidence_calibration.py``'s ``add z``, the
runs of :data:`SHORT_HISTORY_WHITE_SPREAD`), where the 30-frame histories need none. A chart whose reading of its
frame's light was refused (``chart``: ``chart+matrix`` charts neither prior explains, most of the ``illumon``
simulator's) needs 38.3 / 43.4 on 3 / 6 frames; one read as rendered (``chart read as srgb``) nothing (``add z``
0.0 / 0.1), nor one read as a sensor's (``chart read``: the light booth's six-frame histories,
``benchmarks/lightbox.py``, hold their D65 frame on every development camera without it) — a chart's reading
carries its spread. A few frames do not show how the light
moves, which pins a long history's temperatures: a grey card's 95 % intervals held the light's temperature in 73 %
and 64 % of the development frames of 2- and 3-frame histories (86 % and 89 % with these), a chart's through a colour
matrix in 73–86 % of 2–10-frame histories' (92–100 %) (``python benchmarks/unmeasured.py --split dev --seeds 1
--frames F``). Rendered output is not widened: its intervals' shortfall on short histories (70–95 % held) is its
30-frame histories' too (71–85 %), the self-balancing cameras' temperature, not the history's length."""

HISTORY_LENGTHS = (1, 3, 6, 30)
"""The history lengths (frames) the stated spreads were chosen on: :data:`SINGLE_FRAME_WHITE_SPREAD` and
:data:`SINGLE_FRAME_MIRED_SD` (1), :data:`SHORT_HISTORY_WHITE_SPREAD` and :data:`SHORT_HISTORY_MIRED_SD` (3, 6),
:data:`STATED_WHITE_SPREAD` and nothing added (30, the regimes every longer history keeps)."""

_WHITE_SPREAD_BY_LENGTH = {1: SINGLE_FRAME_WHITE_SPREAD, **SHORT_HISTORY_WHITE_SPREAD, 30: {}}
_MIRED_SD_BY_LENGTH = {1: SINGLE_FRAME_MIRED_SD, **SHORT_HISTORY_MIRED_SD, 30: {}}


def history_length_regime(frames: int | None) -> int:
    """Which of :data:`HISTORY_LENGTHS` a scene model fitted on ``frames`` frames states its spreads with: the nearest
    in log frames (2–4 frames: 3; 5–13: 6; 14 and over, or unknown: 30)."""
    if not frames or frames < 1:
        return HISTORY_LENGTHS[-1]
    return min(HISTORY_LENGTHS, key=lambda n: abs(math.log(frames / n)))


BENT_PRIOR = 0.2
"""Prior probability that a history's common temperature is bent: frames no daylight explains (a light booth's
lamps) moved the static patches' shared reflectances, and every frame's temperature with them."""

PRESET_MIRED_SD = 25.0
"""Standard deviation (MK⁻¹) of the light a rendered camera's fixed white balance shows grey, around CIE D65 (the
light the sRGB functions show grey): cameras' "daylight" presets lie at 5 000–6 500 K (154–200 MK⁻¹), their matrices
depart from the sRGB functions by a few more. Chosen from that range, not measured: the development data have no
camera's own preset (``rawsim`` and ``benchmarks/real.py``'s rendered sets balance for D65 or the frames' own greys).
It is the spread of a reference frame's reading of its light through the sRGB functions
(:func:`_reference_balance_level`)."""


def held_or_bent(d: float, var_reading: float, sd_scene: float, sd_bent: float, prior_bent: float = BENT_PRIOR
                 ) -> tuple[float, float, float]:
    """How far to move a history's common reciprocal temperature, given a reading that disagrees with it by ``d``.

    Two hypotheses: the scene's level holds (``d ~ N(0, var_reading + sd_scene²)``: the two are combined by their
    precisions) or frames no daylight explains bent it (``d ~ N(0, var_reading + sd_bent²)``, probability
    ``prior_bent``: the reading is taken). The more probable one is kept; the spread about it is the mixture's (the
    other hypothesis's share and distance widen it). Returns the shift, its standard deviation and the probability
    of the bent hypothesis."""

    def log_n(var: float) -> float:
        return -0.5 * d * d / var - 0.5 * math.log(var)

    log_bent = math.log(prior_bent) + log_n(var_reading + sd_bent**2)
    log_held = math.log(1.0 - prior_bent) + log_n(var_reading + sd_scene**2)
    bent = 1.0 / (1.0 + math.exp(log_held - log_bent))
    held = (d * sd_scene**2 / (sd_scene**2 + var_reading), 1.0 / (1.0 / sd_scene**2 + 1.0 / var_reading))
    shift = d if bent > 0.5 else held[0]
    post_sd = math.sqrt(bent * (var_reading + (d - shift) ** 2) + (1.0 - bent) * (held[1] + (held[0] - shift) ** 2))
    return shift, post_sd, bent


CLIPPED = 0.995
"""Reference values at or above this (observations are 0…1 of the white level) are taken as clipped."""


@lru_cache(maxsize=1)
def prior_sensitivities() -> NDArray[np.float64]:
    """Mean of the measured cameras' max-normalised sensitivities (61 × 3): the camera nobody measured, a priori."""
    return default_camera_prior().mean.copy()


@dataclass
class CameraCalibration:
    """What was learned about the camera: ``C_eff = base @ transform``.

    Attributes
    ----------
    kind
        ``"measured"``, ``"grey"``, ``"chart"`` or ``"none"`` (prior only).
    transform
        ``T`` (3 × 3).
    transform_sd
        Posterior standard deviation of ``T``'s entries (3 × 3; 0 where fixed).
    iterations
        Outer iterations used.
    white_change_deg
        Last change of the D65 camera white between iterations.
    """

    kind: str
    transform: NDArray[np.float64]
    transform_sd: NDArray[np.float64]
    iterations: int
    white_change_deg: float

    def to_dict(self) -> dict:
        """JSON-ready summary (stored in the scene model's ``camera``)."""
        return {
            "calibration": self.kind,
            "transform": self.transform.tolist(),
            "transform_sd": self.transform_sd.tolist(),
            "iterations": self.iterations,
            "white_change_deg": self.white_change_deg,
            "white_sd_log": CAMERA_WHITE_SD[self.kind],
        }


@lru_cache(maxsize=1)
def _d65() -> NDArray[np.float64]:
    return CIEDaylight().spectra(np.array([[1e6 / 6504.0, 0.0]]))[0]


def _d65_white(c: NDArray[np.float64]) -> NDArray[np.float64]:
    return _d65() @ c


def camera_transform_Kinoshita2023(
    base: NDArray[np.float64],
    spectra: NDArray[np.float64],
    illuminants: NDArray[np.float64],
    values: NDArray[np.float64],
    *,
    diagonal: bool,
    relative_error: float = 0.02,
    prior_sd: float = 1.0,
    iterations: int = 20,
    neutral: NDArray[np.bool_] | None = None,
    robust: float = 3.0,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Gaussian posterior of the transform ``T`` in ``C_eff = base @ T`` from references of known reflectance.

    Kinoshita & Kiya's sensitivity posterior (eqs. 15–16) with each output channel's sensitivity in the basis of
    ``base``'s three columns: given the illuminant of every frame, ``values[f, p, c] = s_f · Σ_j T[j, c] u[f, p, j]``
    with ``u[f, p] = baseᵀ (E_f ⊙ R_p)``; the frames' exposures ``s_f`` are eliminated by alternation.

    Parameters
    ----------
    base
        Sensitivities known up to ``T`` (61 × 3).
    spectra
        Reference reflectances (P × 61).
    illuminants
        Illuminant spectra of the frames that show references (F × 61), any scale.
    values
        Their linear camera values (F × P × 3), NaN where a reference is not seen.
    diagonal
        Estimate only each channel's scale (grey cards) instead of the full 3 × 3.
    relative_error
        Relative noise of a reference's value (weights).
    prior_sd
        Prior standard deviation of ``T``'s entries around the identity (in units of the identity's entries).
    iterations
        Alternations between ``T`` and the exposures.
    neutral
        Which references are neutral (P,): after the fit, ``T``'s output channels are scaled so that the neutral
        references' predicted values have the colour they were measured with — the reference frame's white is the
        reference's, exactly (white-point preserving, Finlayson & Drew 1997). A processed camera's pipeline (gamut
        clipping, a tone curve that is not exactly the declared one, local tone mapping) bends chromatic patches more
        than greys; a 3 × 3 fitted to all patches alike would move the greys with them.
    robust
        With a full ``T``: chromatic references whose residual exceeds this many standard errors are down-weighted
        (Cauchy weights, iteratively re-weighted), so a few gamut-clipped patches do not bend the fit.

    Returns
    -------
    transform, transform_sd
        Posterior mean (3 × 3), normalised so the D65 white keeps its green, and standard deviations of its entries.
    """
    u = np.einsum("fl,pl,lj->fpj", illuminants, spectra, base)  # F × P × 3
    ok = np.all(np.isfinite(values), axis=-1) & (values.max(axis=-1) > 0)
    if not ok.any():
        raise ValueError("no reference patch has a usable value")
    s = np.array([
        np.sum(values[f, ok[f], 1]) / max(np.sum(u[f, ok[f], 1]), 1e-300) if ok[f].any() else 1.0
        for f in range(u.shape[0])
    ])
    # Censored values carry no weight: clipped at 0 after the black level (dark patches under a colour matrix) or at
    # the white level (1 on the observations' scale). Weights per channel for T, a mask for the exposures.
    xs = [values[..., c][ok] for c in range(3)]
    weights = [np.where((x > 1e-3 * x.max()) & (x < CLIPPED), 1.0 / (relative_error * np.maximum(x, 1e-12)), 0.0)
               for x in xs]
    good = _fitted_values(values)
    t = np.eye(3)
    sd = np.zeros((3, 3))
    robust_w = [np.ones_like(x) for x in xs]
    for _ in range(iterations):
        t_new = np.zeros((3, 3))
        d = (s[:, None, None] * u)[ok]  # n × 3
        for c in range(3):
            w = weights[c] * robust_w[c]
            dw, xw = d * w[:, None], xs[c] * w
            if diagonal:
                prior = GaussianPrior(np.array([1.0]) * t[c, c], np.array([[1.0 / prior_sd**2]]))
                post = gaussian_posterior(dw[:, [c]], xw, prior, 1.0)
                t_new[c, c] = post.mean[0]
                sd[c, c] = math.sqrt(post.covariance[0, 0])
            else:
                prior = GaussianPrior(np.eye(3)[:, c] * t[c, c], np.eye(3) / prior_sd**2)
                post = gaussian_posterior(dw, xw, prior, 1.0)
                t_new[:, c] = post.mean
                sd[:, c] = np.sqrt(np.diag(post.covariance))
        t = t_new
        pred = np.einsum("fpj,jc->fpc", u, t)
        if not diagonal and robust > 0:
            for c in range(3):
                r = (xs[c] - (s[:, None] * pred[..., c])[ok]) * weights[c]
                robust_w[c] = 1.0 / (1.0 + (r / robust) ** 2)
        s = np.array([
            np.sum((pred[f] * values[f])[good[f]]) / max(np.sum((pred[f] ** 2)[good[f]]), 1e-300) if good[f].any() else 1.0
            for f in range(u.shape[0])
        ])
    if neutral is not None and np.any(neutral):
        t = t @ np.diag(_neutral_scales(values, np.einsum("fpj,jc->fpc", u, t), ok & np.asarray(neutral)[None, :]))
    norm = _d65_white(base)[1] / _d65_white(base @ t)[1]
    return t * norm, sd * abs(norm)


def _fitted_values(values: NDArray[np.float64]) -> NDArray[np.bool_]:
    """The reference values (F × P × 3) :func:`camera_transform_Kinoshita2023` fits: its patch seen in every
    channel, not censored at the black level (at or below 1e-3 of the brightest) nor at white (:data:`CLIPPED`)."""
    ok = np.all(np.isfinite(values), axis=-1) & (values.max(axis=-1) > 0)
    return ok[..., None] & (values > 1e-3 * np.nanmax(values)) & (values < CLIPPED)


def _neutral_scales(values: NDArray[np.float64], pred: NDArray[np.float64], mask: NDArray[np.bool_]) -> NDArray[np.float64]:
    """Per-channel scales (3,) that give the neutral references (``mask``, F × P) the colour they were measured with:
    the ratio of measured to predicted sums over their unclipped values, each frame's own exposure left out."""
    num, den = np.zeros(3), np.zeros(3)
    for f in range(values.shape[0]):
        m = mask[f] & np.all(values[f] < CLIPPED, axis=-1) & np.all(values[f] > 0, axis=-1)
        if not m.any():
            continue
        v, p = values[f, m], pred[f, m]
        k = np.sum(v[:, 1]) / max(np.sum(p[:, 1]), 1e-300)  # the frame's exposure, from green
        num += v.sum(axis=0)
        den += k * p.sum(axis=0)
    if not np.all(den > 0):
        return np.ones(3)
    scale = num / den
    return scale / scale[1]


@lru_cache(maxsize=1)
def prior_white_spread() -> float:
    """Standard deviation (log r/g and b/g, pooled) of the measured cameras' D65 whites around the mean camera's,
    from the shipped camera prior's principal components (each camera max-normalised)."""
    prior = default_camera_prior()
    w0 = _d65_white(prior.mean)
    jac = []
    for j in range(prior.size):
        d = prior.components[:, j].reshape(3, -1).T
        jac.append((log_chroma(_d65_white(prior.mean + 1e-3 * d)) - log_chroma(w0)) / 1e-3)
    cov = np.einsum("ji,j,jk->ik", np.array(jac), prior.variances, np.array(jac))
    return float(np.sqrt(np.trace(cov) / 2))


SCENE_AVERAGE_SD = 0.155
"""Standard deviation (log r/g and b/g) of a scene's average colour around that of the mean measured surface under
the same light: 0.152 (r/g) and 0.157 (b/g), means +0.026 and −0.009, for 280 scenes of ten surfaces drawn from the
development reflectance sets (the five measured sets) under development Granada runs, with the 14 development cameras
(``python tools/scene_average_spread.py``; ``benchmarks/rawsim.py`` splits)."""


def _scene_average_transform(scene: Observations, base: NDArray[np.float64], model, theta
                             ) -> tuple[NDArray[np.float64], float]:
    """Channel scales for a camera with no reference: the Gaussian posterior combining the camera prior (the mean
    camera, spread :func:`prior_white_spread`) with the scene's average colour (gray-world made Bayesian; Buchsbaum
    1980). That average is expected where :mod:`illumon.priors.scene_average` puts it under each frame's estimated
    daylight: the mean measured reflectance's for a scene as varied as the measured surfaces (spread
    :data:`SCENE_AVERAGE_SD`), moving towards grey (spread down to ``SCENE_GREY_SD``) as the patches' colours
    converge — the development lamp-lit scenes average within 0.02–0.09 of grey and 0.2 from the mean measured
    surface, which sent their whites 9–19° off."""
    rb = model.reflectance_basis()
    v = np.asarray(scene.values, dtype=float)
    present = np.all(np.isfinite(v), axis=-1)
    ok = present.sum(axis=1) >= 2
    if not ok.any():
        return np.eye(3), SCENE_AVERAGE_SD
    observed = log_chroma(np.nanmean(np.where(np.isfinite(v[ok]), v[ok], np.nan), axis=1))
    light = model.daylight_model().spectra(theta[ok, :2])
    average = scene_average_evidence(v, present)
    expected = log_chroma(light @ base) + expected_offset(light, base, rb, average)
    shift = np.mean(observed - expected, axis=0)
    s_scene = min(SCENE_AVERAGE_SD, average.sd)
    gain = _camera_white_gain(s_scene)
    log_t = gain * shift
    return np.diag([math.exp(log_t[0]), 1.0, math.exp(log_t[1])]), s_scene


def _camera_white_gain(s_scene: float) -> float:
    """The share of the scene average's reading the camera's channel scales take (the camera prior's spread against
    the reading's ``s_scene``)."""
    s_cam = prior_white_spread()
    return s_cam**2 / (s_cam**2 + s_scene**2)


def scene_calibrated_scale(s_scene: float) -> float:
    """How much a camera nobody measured, calibrated by a scene average read to ``s_scene`` (log r/g, b/g), knows its
    white compared with one calibrated by a scene as varied as the measured surfaces (``SCENE_AVERAGE_SD``, what
    :data:`STATED_WHITE_SPREAD` ``("camera", "none")`` was chosen on): the ratio of the channel scales' posterior
    spreads, ``s_cam·s_scene/√(s_cam² + s_scene²)``, 1 for such a scene, ~0.3 for one of pale surfaces."""
    def post(s: float) -> float:
        return prior_white_spread() * math.sqrt(1.0 - _camera_white_gain(s))
    return post(min(SCENE_AVERAGE_SD, s_scene)) / post(SCENE_AVERAGE_SD)


def calibrate_scene_model(
    obs: Observations,
    sensitivities: NDArray[np.float64] | None,
    known: Mapping[str, NDArray[np.float64]],
    fit: Callable[..., tuple],
    *,
    prior_mean: NDArray[np.float64] | None = None,
    camera_prior: CameraPrior | None = None,
    rendered_prior: CameraPrior | None = None,
    primaries: str = "camera",
    max_iterations: int = 6,
    tol_deg: float = 0.02,
    estimate: Observations | None = None,
    rows: NDArray[np.intp] | None = None,
):
    """Fit a scene model for a camera known only up to ``T`` (see module docstring).

    Parameters
    ----------
    obs
        The history, references included (linear, the camera's output space).
    sensitivities
        Measured (raw) sensitivities, or ``None`` for the prior of the measured cameras.
    known
        References: patch id → reflectance (61,). Empty for none.
    fit
        ``fit(obs, effective_sensitivities, **extra) → (SceneModel, theta)`` with ``theta`` every frame's ``(mired,
        δ, log k)`` (:func:`illumon.model.fit_scene_model`'s fixed-camera fit); ``extra`` may hold
        ``reference_light``: the chart frames' readings of their light (:func:`_chart_readings`).
    prior_mean
        Sensitivities of "a camera nobody measured" (default :func:`prior_sensitivities`; benchmarks pass the mean
        of the cameras of other manufacturers than the one scored).
    camera_prior
        The measured cameras' prior a chart's reading of its light integrates the camera over (default
        :func:`~illumon.priors.default_camera_prior`; benchmarks pass one without the scored camera's maker).
    rendered_prior
        The rendered cameras' prior (default :func:`~illumon.priors.rendered_camera_prior`) a chart's reading falls
        back on when no sensor explains the chart (:func:`_chart_readings`).
    max_iterations, tol_deg
        Outer iterations and the convergence tolerance on the D65 camera white (degrees).
    estimate, rows
        The history whose frames ``rows`` are ``obs`` (default ``obs``): the model is fitted on ``obs`` (a history's
        daylight frames, :func:`illumon.model.fit_scene_model`) and estimates every frame of ``estimate``.

    Returns
    -------
    SceneModel
        With ``camera`` set from :meth:`CameraCalibration.to_dict`.
    """
    if sensitivities is not None:
        base = np.asarray(sensitivities, dtype=float)
    else:
        base = prior_sensitivities() if prior_mean is None else np.asarray(prior_mean, dtype=float)
    kind = references_kind(known) if known else ("measured" if sensitivities is not None else "none")
    t = np.eye(3)
    sd = np.zeros((3, 3))
    ids = [p for p in obs.patches if p in known]
    scene = obs.select_patches([p for p in obs.patches if p not in known]) if ids else obs
    extra = {}
    chart_space = "camera"  # the output space a chart's colours are read in (:func:`_chart_readings`)
    if ids:
        values, frames, spectra, neutral = _reference_data(obs, scene, ids, known)
        if kind == "chart" and sensitivities is None and primaries == "camera":
            readings, chart_space = _chart_readings(values, frames, spectra, camera_prior, rendered_prior)
            if readings is not None:
                extra["reference_light"] = readings
    model, theta = fit(scene, base, **extra)
    theta_first = np.array(theta, dtype=float, copy=True)
    change, it = 0.0, 0
    s_scene = None  # how precisely a scene average set the channel scales (no reference, sensor RGB)
    glare_sd = 0.0  # how far the reference frames' glare leaves the camera white (log r/g, b/g)
    if ids:
        dm = model.daylight_model()
        if primaries == "srgb":  # rendered output: the reference iterations hold the first fit's level
            extra["common_level"] = _held_level(model, theta)
        # The references are left out of the scene fit: a reference seen in one frame cannot tell a shift common to
        # every frame's daylight from a change of T, so the frames' daylight comes from the scene (as without
        # references) and T absorbs the rest, pinning the camera white of the reference frames.
        model, theta, t, sd, it, change = _read_until_held(
            model, theta, t, sd, base,
            lambda m, th: camera_transform_Kinoshita2023(base, spectra, dm.spectra(th[frames, :2]), values[frames],
                                                         diagonal=(kind == "grey"), neutral=neutral),
            lambda c: fit(scene, c, **extra), max_iterations, tol_deg)
        glare_sd = _glare_white_sd(base, spectra, dm.spectra(theta[frames, :2]), values[frames], kind == "grey",
                                   neutral, _reference_offset_sd(obs, frames, model.noise.get("flare_sd", 0.0)))
    if kind == "none" and primaries == "camera":
        # A rendered camera's own white balance already set its channel scales; its prior is in the daylight model.
        # The lamp-lit-or-daylight verdict is weighed through the prior camera, before the transform: the transform
        # reads the scene average as daylight's, which makes the two components' levels nearly one in the refit while
        # the light's temperature still hangs on the verdict (illumon.model.level.verdict_shift)
        verdict = {k: v for k, v in model.noise.get("model_error", {}).items() if k.startswith("verdict_")}
        # judged lamp-lit (:mod:`illumon.model.level`), the scene's colour is the lamps': read once
        rounds = 1 if float(model.noise.get("unbalanced", 0.0) or 0.0) > 0.5 else max_iterations
        # read again at the refit's light until the scales hold: the refit's light relaxes towards the daylight
        # prior's once the scales explain the scene's colour, which leaves the first scales short
        model, theta, t, s_scene, it, change = _read_until_held(
            model, theta, t, s_scene, base, lambda m, th: _scene_average_transform(scene, base, m, th),
            lambda c: fit(scene, c), rounds, tol_deg)
        me = model.noise.setdefault("model_error", {})
        for k in [k for k in me if k.startswith("verdict_")]:  # the refit's own (illumon.model.intervals.VERDICT_KEYS)
            me.pop(k)
        me.update(verdict)
        # how far the light's temperature moved when the scene's colour went from the light (the first fit, through
        # the prior camera) to the channel scales: where between the two the truth lies, the scene cannot say
        split = _common_mired_shift(theta_first, theta)
        model.noise["split_mired"] = split if math.isfinite(split) else 0.0
    model.camera = CameraCalibration(kind, t, sd, it, change).to_dict()
    if "reference_light" in extra:
        model.camera["chart_read_as"] = chart_space
    _record_camera_uncertainty(model, kind, primaries, measured=sensitivities is not None, scene_sd=s_scene,
                               glare_sd=glare_sd)
    if ids and primaries == "srgb":
        model.noise["mired_offset"] = _reporting_offset(theta_first, theta)
        _reference_balance_level(model, theta[frames], values[frames], spectra, neutral, base)
    if estimate is not None:  # every frame of the whole history; the fit's frames as its rows
        scene = estimate.select_patches(list(scene.patches))
        if model.fit_frames is not None:
            model.fit_frames = np.asarray(rows)[model.fit_frames]
        if ids:
            values, _, _, _ = _reference_data(estimate, scene, ids, known)
    model.history_estimate = model.estimate(scene)  # with the camera's uncertainty in its intervals
    if ids:
        _reference_frames_white(model.history_estimate, values, spectra, neutral, base @ t,
                                estimate if estimate is not None else obs,
                                float(model.noise.get("flare_sd", 0.0) or 0.0))
    return model


def _read_until_held(model, theta: NDArray[np.float64], t: NDArray[np.float64], aux, base: NDArray[np.float64],  # noqa: ANN001
                     read: Callable[..., tuple], refit: Callable[[NDArray[np.float64]], tuple], rounds: int,
                     tol_deg: float) -> tuple:
    """:func:`calibrate_scene_model`'s block coordinate descent on ``T`` and the scene: ``read(model, theta)`` gives
    the transform at the current fit and what came with it (``aux``: its posterior spread, or the scene average's
    precision), ``refit(base @ T)`` the scene fitted through it, until the camera's D65 white moves by less than
    ``tol_deg`` or after ``rounds`` rounds. Returns the model, ``theta``, ``T``, the last ``aux``, the rounds run and
    the last change (degrees); the inputs unchanged where ``rounds`` is 0."""
    it, change = 0, 0.0
    for it in range(1, rounds + 1):  # noqa: B007
        t_new, aux = read(model, theta)
        change = float(angular_error_deg(_d65_white(base @ t), _d65_white(base @ t_new)))
        t = t_new
        model, theta = refit(base @ t)
        if change < tol_deg:
            break
    return model, theta, t, aux, it, change


def _reference_data(obs: Observations, scene: Observations, ids: list[str], known: Mapping[str, NDArray[np.float64]]
                    ) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.float64], NDArray[np.bool_]]:
    """The references' values (F × R × 3), the frames that show a reference and at least two scene patches, the
    references' spectra (R × 61) and which of them are neutral; raises when no frame shows both."""
    values = np.asarray(obs.values, dtype=float)[:, [obs.patches.index(p) for p in ids]]
    seen = np.all(np.isfinite(values), axis=-1).any(axis=1)
    frames = np.flatnonzero(seen & (np.all(np.isfinite(scene.values), axis=-1).sum(axis=1) >= 2))
    if not frames.size:
        raise ValueError("reference patches must appear in a frame that also shows at least two scene patches "
                         "(their daylight is estimated from the scene)")
    spectra = np.stack([known[p] for p in ids])
    neutral = np.array([p in set(neutral_references({q: known[q] for q in ids})) for p in ids])
    return values, frames, spectra, neutral


def _chart_readings(values: NDArray[np.float64], frames: NDArray[np.int64], spectra: NDArray[np.float64],
                    prior: CameraPrior | None, rendered: CameraPrior | None = None
                    ) -> tuple[tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]] | None, str]:
    """Each reference frame (``frames``, :func:`_reference_data`'s, with its ``values`` and ``spectra``) that shows
    enough of the chart: its light's reciprocal temperature read from the chart with the camera integrated out
    (:func:`~illumon.camera.chart_light.chart_light_illumon`) — frame indices, readings (MK⁻¹) and their standard
    deviations, or ``None`` when no frame gives one — and the output space the charts were read in. Sensor RGB of a
    camera nobody measured: rendered output's channels are no camera's sensitivities, and a measured camera's light
    is read with them.

    A camera declared sensor RGB may still render: an industrial camera with its colour correction on applies a
    matrix towards sRGB primaries. No sensor of ``prior`` (default :func:`~illumon.priors.default_camera_prior`)
    then explains its chart (misfit 1.08–1.34 on 14 development cameras under a D65 simulator, CIE A and a D50
    simulator), and the reading was refused — a light booth's D65 frame then read 16 900 K. The charts are then read
    with the rendered cameras' prior (``rendered``, default :func:`~illumon.priors.rendered_camera_prior`, the
    measured cameras carried to sRGB primaries), which explains them (misfit 0.48–0.94, readings −8…+11 MK⁻¹ under the
    D65 simulator) and refuses the sensors' charts (1.05–1.41): ``python tools/chart_output_space.py``. The two
    are not mixed: the charts are read in the first output space (the sensors', then the rendered cameras') in which
    any of them is read, and the frames it refuses give no reading."""
    spaces = (("camera", prior if prior is not None else default_camera_prior()),
              ("srgb", rendered if rendered is not None else rendered_camera_prior()))
    shown = frames[np.all(np.isfinite(values[frames]), axis=-1).sum(axis=1) >= 6]
    for space, p in spaces:
        found = []
        for f in shown:
            reading = chart_light_illumon(values[f], spectra, p)
            if reading is not None:
                found.append((int(f), reading.mired, reading.sd))
        if found:
            f, mired, sd = (np.array(c) for c in zip(*found, strict=True))
            return (f.astype(np.int64), mired.astype(float), sd.astype(float)), space
    return None, "camera"


def _held_level(model, theta: NDArray[np.float64]) -> tuple[float, float, float, float]:  # noqa: ANN001
    """A level a rendered camera's reference iterations hold their fits at (``common_level`` of
    :func:`illumon.model.fit_scene_model`'s fixed-camera fit): the fit's (``model``, ``theta``) median ``(mired, δ)``
    — the first fit's is anchored to the camera's own balance through the sRGB functions — and the model errors it
    stated for that common level.

    A reference seen in one frame cannot tell a shift common to every frame from a change of ``T``: refitted at the
    effective sensitivities ``base @ T``, the balance anchor (the history's mean white near grey through them) moves
    the level, ``T`` follows to keep the reference frame's white, and the two chase each other. The chase has no
    fixed point: on daylight with a grey card it moved the level by up to 31 MK⁻¹ an iteration, most histories still
    moving at the sixth and last (the 56 development ``grey+rendered`` and ``grey+awb`` histories; the Nikon D300s of
    ``unmeasured.py``'s ``grey+awb``, seed 7 200: 146 → 263 MK⁻¹, ``T`` diagonal (0.57, 1, 1.93), whites 5.5° off
    where the held level's are 1.0°), so where it stopped was set by the iteration count. Every rendered reference
    holds the first fit's level from the start. Medians chased → held, ``python benchmarks/unmeasured.py --split
    dev``: ``chart+rendered`` and ``chart+awb``, with and without ``--flare`` (``--seeds 1``), ``rawsim`` 0.88 → 0.38°,
    1.19 → 0.45°, 1.52 → 0.88°, 1.34 → 0.92°; ``grey+rendered`` and ``grey+awb`` (``--seeds 2``), ``illumon``
    1.50 → 1.33°, 1.63 → 1.42°, ``rawsim`` 1.22 → 0.35°, 1.59 → 0.50°; with ``--flare`` the grey cards' medians lose
    0.18–0.63° — the chase had let the anchor outweigh a card the glare had moved — and their worst frames gain,
    28–30° → 11°.
    In a light booth (a rendered camera, a chart under a D65 simulator, the other frames
    tungsten and fluorescent lamps whose mean white is far from grey) no level satisfies both, and every frame's
    temperature ran to the locus's end, where frames lit by D65 and by a D50 simulator were read as the same light, the
    latter's white 9.7° off (``python benchmarks/lightbox.py --matrix --primaries srgb``)."""
    me = model.noise["model_error"]
    mired, delta = np.median(np.asarray(theta, dtype=float)[:, :2], axis=0)
    return float(mired), float(delta), float(me["common_mired"]), float(me["common_duv"])


def _reference_balance_level(model, theta: NDArray[np.float64], values: NDArray[np.float64],  # noqa: ANN001
                             spectra: NDArray[np.float64], neutral: NDArray[np.bool_], base: NDArray[np.float64]
                             ) -> None:
    """A rendered camera's reference frames read their own light (in place: ``noise["mired_offset"]`` and the common
    level's model error).

    The history's reported temperature rests on the camera's balance: its mean white is expected near grey
    (:func:`illumon.model.level.common_level_posterior`). A history lit mostly by lamps (a light booth) breaks that
    — its mean white is warm — and every frame's temperature moves with it: the booth's D65 frame read 12 300 K. A
    reference frame's neutral white is a second reading of the same level: through the sRGB functions (the camera's
    fixed balance, ± :data:`PRESET_MIRED_SD`) it names the locus light that shows it. The two are weighed as
    :func:`held_or_bent` weighs them (the daylight prior's spread for the bent hypothesis): the reported temperature
    moves by the shift and the common level's spread becomes the mixture's (CCT and Duv intervals only: the
    references pin the whites). ``theta``: the reference frames' ``(mired, δ, …)`` in the model's last fit; ``values``:
    their reference values (frames × references × 3); ``base``: the sRGB functions. Nothing changes without unclipped
    neutral references, or when no locus light inside the model's range shows them grey."""
    if not np.any(neutral):
        return
    dm = model.daylight_model()
    frames = np.flatnonzero(np.all(np.isfinite(values[:, neutral]), axis=-1).any(axis=1))
    lo, hi = dm.bounds()
    mired, delta = np.meshgrid(np.arange(lo[0], hi[0] + 0.5, 1.0), np.arange(-0.02, 0.0205, 0.001))
    grid = np.stack([mired.ravel(), np.clip(delta.ravel(), lo[1], hi[1])], axis=1)  # the locus and off it
    e = dm.spectra(grid)
    offset = float(model.noise.get("mired_offset", 0.0))
    diffs = []
    for f in frames:
        v = values[f][neutral]
        ok = np.all(np.isfinite(v), axis=-1) & np.all(v < CLIPPED, axis=-1) & np.all(v > 0, axis=-1)
        if not ok.any() or not np.all(np.isfinite(theta[f, :2])):
            continue
        pred = np.einsum("rl,gl,lc->gc", spectra[neutral][ok], e, base)  # the neutrals' sum through base
        seen = v[ok].sum(axis=0)
        with np.errstate(divide="ignore", invalid="ignore"):  # the CIE basis goes negative at the grid's corners
            chroma = np.log(seen[[0, 2]] / seen[1]) - np.log(pred[:, [0, 2]] / pred[:, 1:2])
        dist = np.where(np.all(pred > 0, axis=1), np.sum(chroma**2, axis=1), np.inf)
        read = float(grid[np.argmin(dist), 0])
        if read <= lo[0] or read >= grid[-1, 0]:
            continue  # no locus light shows these neutrals grey through the sRGB functions: no reading
        diffs.append(read - (theta[f, 0] + offset))
    if not diffs:
        return
    me = model.noise["model_error"]
    # one preset for every reference frame: their readings share its error, so it does not average out
    shift, sd, _ = held_or_bent(float(np.mean(diffs)), PRESET_MIRED_SD**2, float(me["common_mired"]),
                                float(dm.mired_sigma))
    model.noise["mired_offset"] = offset + shift
    me["common_mired"] = sd


def _reporting_offset(theta_first: NDArray[np.float64], theta: NDArray[np.float64]) -> float:
    """The reciprocal-temperature offset (MK⁻¹) a rendered camera with references reports its light with.

    Rendered output: the history's common level is anchored to the camera's own balance as the effective
    sensitivities see it (:func:`illumon.model.level.anchor_common_level`), which moves with T, so the iterations let
    T and the common temperature chase each other along the direction a reference cannot see (on development cameras
    the CCT ends 34–38 MK⁻¹ RMS off, though the whites gain from the iterations). The temperature is read as the sRGB
    functions saw it before the reference moved the camera: the shift common to every frame between the first fit
    and the last is kept as a reporting offset (CCT, Duv, spectrum)."""
    return -_common_mired_shift(theta_first, theta)


def _common_mired_shift(theta_first: NDArray[np.float64], theta: NDArray[np.float64]) -> float:
    """The reciprocal-temperature shift (MK⁻¹) common to every frame from the first fit (``theta_first``, F × 2
    ``(mired, δ)``) to the last (``theta``): the median over frames of each frame's move, NaN-frames left out. Both the
    rendered cameras' reporting offset (:func:`_reporting_offset`) and the temperature's spread a scene average adds
    (``noise["split_mired"]``) read it."""
    return float(np.nanmedian(theta[:, 0] - theta_first[:, 0]))


def _reference_offset_sd(obs: Observations, frames: NDArray[np.int64], flare_sd: float) -> NDArray[np.float64] | None:
    """Prior spread of the reference frames' additive offsets (len(frames) × 3): the scene fit's own
    (:func:`~illumon.camera.formation.flare_scales`: the history's learned glare spread times each frame's mean value
    in each channel), over every patch the frame shows, references included; ``None`` without glare."""
    v = np.asarray(obs.values, dtype=float)[frames]
    seen = np.broadcast_to(np.all(np.isfinite(v), axis=-1)[..., None], v.shape)
    return flare_scales(v, seen, flare_sd, 0.0)


def _glare_white_sd(base: NDArray[np.float64], spectra: NDArray[np.float64], illuminants: NDArray[np.float64],
                    values: NDArray[np.float64], diagonal: bool, neutral: NDArray[np.bool_],
                    offset_sd: NDArray[np.float64] | None, step: float = 0.01) -> float:
    """How far veiling glare in the reference frames moves the camera white ``T`` is fitted to (log r/g and b/g,
    pooled, one standard deviation): light scattered in the lens adds a fraction of each frame's mean radiance to the
    references as to everything else (:data:`illumon.camera.formation.FLARE_SD`), which ``T`` takes for the camera's
    own. Each reference frame's offset, ``offset_sd`` (:func:`_reference_offset_sd`: the history's learned glare
    spread along the frame's mean colour), is added to its references in turn and the D65 white's derivative along
    it (central differences of ± ``step`` of it) summed in quadrature: little when the scene's mean has the
    references' colour or a chart's dark and light patches fix it, most for a grey card among coloured surfaces.
    Only the values the fit uses move: a value censored at 0 (a colour matrix took it below) or at the white level
    stays censored, as its weight would otherwise jump in or out of the fit (on a development chart under an
    automatic white balance, a channel at 0 lifted into the fit by the step made the "derivative" 0.33 instead of
    0.02); and the step is small, as a chart's robust weights can settle elsewhere after a larger one (a development
    chart: 0.109 with a step of 0.05, 0.0358 with 0.02, 0.01 and 0.005)."""
    if offset_sd is None:
        return 0.0

    def white(v: NDArray[np.float64]) -> NDArray[np.float64]:
        t, _ = camera_transform_Kinoshita2023(base, spectra, illuminants, v, diagonal=diagonal, neutral=neutral)
        return log_chroma(_d65_white(base @ t))

    used = _fitted_values(values)
    var = 0.0
    for f in range(values.shape[0]):
        delta = np.zeros_like(values)
        delta[f] = np.where(used[f], step * offset_sd[f], 0.0)
        var += float(np.sum(((white(values + delta) - white(values - delta)) / (2 * step)) ** 2))
    return math.sqrt(var / 2)


def camera_mired_key(model, kind: str, measured: bool = False) -> str:
    """The key of :data:`CAMERA_MIRED_SD` (and of the short histories' and single frames' spreads) a calibrated model
    states its temperature's spread with: ``measured``, ``grey``, ``none``, or a chart's — ``chart`` when its reading
    of its frame's light was refused, ``chart read`` when read as a sensor's, ``chart read as srgb`` when only the
    rendered cameras' prior explained it."""
    if measured:
        return "measured"
    if kind == "chart" and "chart_level" in model.noise:  # the frames' light read from the chart too
        return "chart read as srgb" if model.camera.get("chart_read_as") == "srgb" else "chart read"
    return kind


def _record_camera_uncertainty(model, kind: str, primaries: str, *, measured: bool,
                               scene_sd: float | None = None, glare_sd: float = 0.0) -> None:
    """The camera's own uncertainty after calibration, in the model: ``camera["white_sd_log"]`` and the model errors
    ``camera_log_gain`` and ``camera_mired`` its intervals widen by. Rendered output: a grey card pins channel scales,
    but not how a real camera's matrix departs from the sRGB functions away from the card's light (a chart's 3 × 3
    does). ``scene_sd``: how precisely the scene average set the channel scales, where it did
    (:func:`scene_calibrated_scale`). ``glare_sd``: what the reference frames' veiling glare leaves uncertain in the
    camera white (:func:`_glare_white_sd`), added in quadrature to the stated spread (``camera_glare_log``)."""
    white_sd = SRGB_CAMERA_WHITE_SD if (kind in ("none", "grey") and primaries == "srgb") else CAMERA_WHITE_SD[kind]
    model.camera["white_sd_log"] = white_sd
    key = camera_mired_key(model, kind, measured)
    mired_sd = (SRGB_CAMERA_MIRED_SD if primaries == "srgb" else CAMERA_MIRED_SD)[key]
    length = history_length_regime((getattr(model, "training", None) or {}).get("frames"))
    if not measured:  # a short history does not show how its light moves, which pins a long one's temperatures
        mired_sd = math.hypot(mired_sd, _MIRED_SD_BY_LENGTH[length].get((primaries, key), 0.0))
        # the scene's colour split between the channel scales and the light (calibrate_scene_model, no reference)
        mired_sd = math.hypot(mired_sd, float(model.noise.get("split_mired", 0.0)))
    table = {**STATED_WHITE_SPREAD, **_WHITE_SPREAD_BY_LENGTH[length]}
    scale, stated, glare_k = ((1.0, white_sd, 1.0) if measured
                              else table.get((primaries, kind), (1.0, white_sd, 1.0)))
    if scene_sd is not None:  # the scene average calibrated the channel scales: as well as it read
        scale *= scene_calibrated_scale(scene_sd)
    model.noise["model_error"] = dict(model.noise.get("model_error", {}),
                                      camera_log_gain=math.hypot(stated, glare_k * glare_sd),
                                      camera_glare_log=glare_sd, camera_mired=mired_sd, laplace_scale=scale)


REFERENCE_WHITE_SD_DEG = 0.25
"""Angular standard deviation (degrees) of a camera white read off neutral references in its own frame: the spread of
a ColorChecker's greys 20–22 about their mean on the development photographs (``benchmarks/real.py``) is 0.1–0.3°."""


MID_GREY = 0.18
"""Reflectance of the grey a reference frame's white is stated for (:func:`_glare_reference_tr`): the photographic
mid grey, a grey card's."""


def _glare_reference_tr(white: NDArray[np.float64], summed: NDArray[np.float64], n: int,
                        glare_sd: NDArray[np.float64]) -> float:
    """What veiling glare leaves uncertain in a reference frame's white read off ``n`` neutrals whose values sum to
    ``summed`` (3,), taken as the white a grey of :data:`MID_GREY` gives in the same frame: the trace (rad²) of the
    white direction's covariance, to first order, for a glare offset along the frame's mean colour of one standard
    deviation (``glare_sd``, 3: the history's learned glare spread times the frame's mean value in each channel,
    :func:`_reference_offset_sd`). Light scattered in the lens adds a share of the scene's mean radiance to every
    patch alike, so it moves the white read off a dark neutral most (a black patch's log white by ``n/Σv − 1/v_mid``
    per unit of offset), a mid grey's not at all, and a light one's a little the other way; a neutral scene's glare
    moves no white. The truth the outside checks score is the frame's own mid greys (a ColorChecker's 20–22), and a
    mid grey is what the camera's gains are to make grey.

    On the development photographs with only some of the chart's greys known (``python benchmarks/real.py
    --subsets``) the reference frame's white was 1.1–3.1° off its greys 20–22 with the black patch as the
    reference, 0.7–1.8° with the two darkest greys, 0.05–0.7° with the white, 0.2–0.6° with one or three mid greys,
    where this spread (with :data:`REFERENCE_WHITE_SD_DEG`) states an RMS of 1.8–4.0°, 0.9–2.0°, 0.65–1.2° and
    0.4–1.0°; the grey-card frames of the simulators (reflectance :data:`MID_GREY`) state as before. Glare taken as
    independent in each channel (the fit's prior, :func:`~.formation.flare_scales`) stated 4–10 times more."""
    w = np.asarray(white, dtype=float)
    mid = MID_GREY * w
    k = n / np.asarray(summed, dtype=float) - 1.0 / mid  # d log(white)_c / d offset_c, relative to a mid grey
    u = w / np.linalg.norm(w)
    jac = (np.eye(3) - np.outer(u, u)) @ np.diag(w * k) / np.linalg.norm(w)  # the direction's move per offset
    return float(np.sum((jac @ np.asarray(glare_sd, dtype=float)) ** 2))


def _reference_frames_white(estimate: tuple, values: NDArray[np.float64], spectra: NDArray[np.float64],
                            neutral: NDArray[np.bool_], sensitivities: NDArray[np.float64],
                            seen: Observations | None = None, flare_sd: float = 0.0) -> None:
    """A frame that shows neutral references gets its white from them (in place): each unclipped neutral's measured
    value divided by its predicted value relative to the white under the frame's estimated light (which corrects a
    chart grey's slight colour), summed over the neutrals; its gains follow, with intervals and ``confidence`` from
    :data:`REFERENCE_WHITE_SD_DEG` and, where the history learned a glare spread (``flare_sd``; ``seen``: the
    history ``values`` are the references of, for each frame's offset spread, :func:`_reference_offset_sd`), what the
    glare leaves in a white read off neutrals darker or lighter than a mid grey (:func:`_glare_reference_tr`). Other
    frames are untouched, and only the frames that show a neutral are visited (a long history's others are most)."""
    result, extra = estimate
    if not np.any(neutral):
        return
    rows = np.flatnonzero(np.any(np.all(np.isfinite(values[:, neutral]), axis=-1), axis=1))
    glare = None if seen is None else _reference_offset_sd(seen, rows, flare_sd)
    for i, f in enumerate(rows.tolist()):
        v = values[f][neutral]
        ok = np.all(np.isfinite(v), axis=-1) & np.all(v < CLIPPED, axis=-1) & np.all(v > 0, axis=-1)
        e = np.asarray(result.spectra[f], dtype=float)
        if not ok.any() or not np.all(np.isfinite(e)):
            continue
        rel = ((spectra[neutral][ok] * e) @ sensitivities) / (e @ sensitivities)  # each neutral relative to white
        summed = v[ok].sum(axis=0)
        white = summed / rel.sum(axis=0)
        if not np.all(white > 0):
            continue
        tr = 2 * math.radians(REFERENCE_WHITE_SD_DEG) ** 2
        if glare is not None:
            tr += _glare_reference_tr(white, summed, int(ok.sum()), glare[i])
        white = white / white[1]
        result.white[f] = white
        result.gains[f] = 1.0 / white
        extra["confidence"][f] = within_one_degree(tr)
        half = Z95 * math.sqrt(tr) * result.gains[f]
        result.info["gain_lo"][f] = result.gains[f] - half
        result.info["gain_hi"][f] = result.gains[f] + half
