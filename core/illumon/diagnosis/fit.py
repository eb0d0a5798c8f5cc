"""Diagnose a history: fit the linear model, fit every effect as an explicit physical extension, select by BIC.

Two stages, each a penalised-likelihood comparison against its own base model (Schwarz 1978):

1. **Bilinear stage** (:func:`.stages.bilinear_stage`, :mod:`.bilinear`): the camera-agnostic rank-4 factorisation
   of frames × (patches·channels), Gaussian noise of a patch mean ``σ² = φ·(a·y + b)`` with ``a`` and ``b``
   **learned from the history's own residuals** (:func:`.bilinear.estimate_noise`, Poissonian-Gaussian, Foi et al.
   2008; at least the quantisation
   noise of values delivered on an 8…16-bit grid; values at 0 censored), ``φ`` profiled, ``BIC = 2·NLL + k·ln n``.
   Extensions: tone curve (γ, sRGB or BT.709), black offset (3 pedestals), clipping (censored values at the clip
   level; named without the ΔBIC when a channel is held at the white level, :func:`.stages.held_at_white`), patch
   change (patch, onset), shadow (patch, run, per-channel scale). The tone curve is judged with each
   hypothesis's own learned noise in its linear light (shot noise carrying at least 90 % of the variance at the median
   signal; for values delivered as codes, plus the output rounding's variance step²/12 carried into that light through
   the curve's slope), the
   Jacobian of the curve, Huber's loss and the values within 3 % of black censored (:data:`.noise.DARK_LEVEL`),
   or more while the band above the censoring level misfits the learned noise (:data:`.tone.ADAPTIVE_DARK`: output
   rounding that the pixel noise does not dither). The black offset is judged on the values above
   :data:`.noise.DARK_LEVEL` too (base and extension alike).
   Patch change and shadow are scored in units of the patches' median residual variance, or of the patch's own under
   the alternative when larger.
2. **Spectral stage** (:func:`.stages.spectral_stage`, :mod:`.spectral`), only when no bilinear extension is
   supported: off-locus light and fluorescence, which the bilinear model cannot see, against the joint spectral fit
   (values near black censored).

An extension is chosen when its BIC beats the base by more than :data:`NONE_MARGIN`; the margins are set
on the development cameras of both simulators, so that they hold beyond the project's own (:mod:`illumon.simulation.simulate` via
:mod:`illumon.simulation.effects`, and the independent raw pipeline ``benchmarks/rawsim.py``: Nikon and Point Grey
bodies, development surfaces and daylight, seeds 3 000…); otherwise the answer is ``none``.

The spectral effects' scores are not ΔBIC: the spectral model's own misfit (reflectance basis, daylight model), not the
noise, sets the scale of their gains, so each is measured against the history itself.

* **Off-locus light** (:func:`.spectral.off_locus_gains`; daylight is the Gaussian mixture of measured Granada skies,
  :func:`.spectral.daylight_mixture`): each frame's gain from a free illuminant in units of the history's typical
  frame (median gain read as the median of χ²₅), ``z``; score ``min_k Σ_{top k} (τ − z)``, ``k`` = 2…F/3 frames,
  ``τ`` = :data:`.stages.OFF_LOCUS_FRAME_Z` = 10. Margin 4 when set on the project's simulator alone (the 1st
  percentile of the score on 200 clean development histories of the project's simulator, −3.6); 14 with both
  simulators (clean raw-pipeline histories reach −13).
* **Fluorescence** (:func:`.spectral.generic_fluorescence_gains`, Han et al. 2012 eqs. 1–2): the best patch's gain
  from an emission driven by a generic short-wave band, of any colour light above that band gives (the Stokes shift:
  :func:`.spectral.emission_cone`), divided by the largest gain of any other patch
  (at least the median of χ²₃); score minus that ratio. The gains are externally studentised
  (:func:`.spectral.studentised_fluorescence_ratio`: each patch against the lights, reflectances and noise scale
  re-fitted without it, the best of the three largest in-sample gains so measured, the other patches also without
  it) and the reflectances' prior is a Student t
  (:data:`.spectral.REFLECTANCE_PRIOR_DOF`, fitted to the measured reflectances), so neither a surface the lights
  fitted with it misfit nor one the Gaussian prior shrinks reads as fluorescent, and a fluorescent patch no longer
  raises the other patches' gains through the lights it bent. Margin 2.3 when set on the project's simulator alone
  (the 98th percentile of the ratio on 200 clean development histories of the project's simulator); 3.0 with both
  simulators (see :data:`NONE_MARGIN`), kept for the studentised ratio; 5.0 since the emission lies above its band.

Off-locus light is tested first (its misfit can make a patch look fluorescent, not the reverse), with the best
fluorescent-looking patch left out when its ratio passes the margin. The illuminants are then re-estimated with the
chosen extension (:func:`.correction.corrected_observations`, :func:`.correction.estimate_with_effect`) and the
change is reported.
"""

from __future__ import annotations

import copy
import warnings
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from .._blas import single_blas_thread
from ..camera import angular_error_deg
from ..camera.primaries import check_primaries
from ..model import fit_scene_model
from ..model.lamps import frame_verdicts, unbalanced_probability
from ..observations import Observations
from ..retrieval import retrieve_illuminants
from .candidate import NONE_MARGIN, RANK, Candidate
from .correction import Diagnosis, corrected_observations, estimate_with_effect
from .noise import CODEC_NOISE, dark_level, dark_level_set, history_dark_level
from .spectral import lamp_shares, spectral_pedestal
from .stages import (
    MIN_OFF_LOCUS_FRAMES,
    MIN_OFFSET,
    MINOR_CLIPPING_FRACTION,
    bilinear_stage,
    daylight_reflectances,
    pedestal_allowed,
    refined_spectral_base,
    spectral_stage,
    supported,
)

if TYPE_CHECKING:
    from ..model import SceneModel

__all__ = ["RANK", "NONE_MARGIN", "MIN_OFF_LOCUS_FRAMES", "SHORT_HISTORY_FRAMES", "Candidate", "diagnose", "min_frames",
           "short_history_hint"]

GLOBAL_EFFECTS = ("nonlinear_response", "black_offset", "clipping")
"""Bilinear effects that act on every value (unlike a patch change or shadow, which name their own patch and frames)
and so can be mimicked by lamp-lit frames or a fluorescent patch the bilinear model cannot describe."""


def _spectral_cause(obs: Observations, sensitivities: NDArray[np.float64], rank: int, chosen: Candidate,
                    spectral: list[Candidate], margins: dict[str, float], learn_noise: bool,
                    from_images: bool = False) -> Candidate | None:
    """The spectral effect that explains a bilinear one, or None.

    Lamp-lit frames break the daylight's rank-4 structure and a fluorescent patch adds light the reflectances do not
    (Han et al. 2012): the bilinear stage may then read a tone curve, a pedestal or clipped values into them (a sodium
    lamp's red saturating while the metering reads green). When a spectral effect passes its own margin too, the
    bilinear stage is run again without its frames (off-locus) or its patch (fluorescence); if no evidence of the
    global effect is left there (ΔBIC ≥ 0: not merely weaker, as any effect is on fewer values), the spectral effect
    is its cause (without this, raw-pipeline histories with a lamp read as a tone curve at ΔBIC −198, +5.9 without the
    lamp-lit frames, or as clipping at −320; a weak tone curve with a patch that looks fluorescent keeps −22 without
    that patch and stays a tone curve). Clipping is not put down to fluorescence: a patch whose values clip misfits
    the spectral model by that alone (a development history clipped in one patch passed the fluorescence margin).
    The converse is checked too: when the spectral effect no longer passes its margin once the global effect is
    modelled (values linearised, offsets subtracted, clipped values dropped), the global effect explains it and
    stays (a tone curve on values rounded to codes: its misfit of the spectral model read as lamp light, −57, which
    linearising removes). A patch change or a shadow is put down to lamp light the same way (lamp-lit frames late in
    an image-based history read as a patch changing at their onset, ΔBIC −42 against the lamp's −67), and to
    fluorescence of *another* patch (an emission distorts the frame factors the other patches are judged against: a
    patch "changing" at frame 24 beside a fluorescent patch at −17); never to fluorescence of the changed or shaded
    patch itself, which misfits the spectral model by that alone (three development histories read so).
    """
    y = obs.values.reshape(obs.values.shape[0], -1)
    se = _image_se(obs, from_images)
    modelled: list[Candidate] | None = None
    for cand in spectral:  # off-locus light first, as in the selection
        if not cand.score < -margins[cand.effect]:
            continue
        if cand.effect == "fluorescence" and chosen.effect == "clipping":
            continue  # the clipped patch misfits the spectral model too: no independent evidence of emission
        if cand.effect == "fluorescence" and chosen.patch is not None and cand.patch == chosen.patch:
            continue  # so does a changed or shaded patch
        masked = y.copy()
        se_kept = se
        if cand.effect == "off_locus_illuminant":
            keep = np.setdiff1d(np.arange(y.shape[0]), cand.parameters["frame_indices"])
            if keep.size < rank + 2:
                continue
            masked = masked[keep]
            se_kept = None if se is None else se[keep]
        else:
            masked[:, 3 * cand.patch : 3 * cand.patch + 3] = np.nan
        _, again, _ = bilinear_stage(masked, rank, margins["clipping"], learn_noise, *_image_noise(from_images),
                                     se=se_kept)
        if supported(next(c for c in again if c.effect == chosen.effect), 0.0):  # it stands without the spectral one
            continue
        if modelled is None:
            as_chosen = Diagnosis(chosen.effect, None, None, dict(chosen.parameters), [], 0.0, 0.0, None,
                                  patch_index=chosen.patch, frame_index=chosen.frame)
            modelled, _ = spectral_stage(corrected_observations(obs, as_chosen), sensitivities,
                                         margins["fluorescence"])
        again_cand = next(c for c in modelled if c.effect == cand.effect)
        if again_cand.score < -margins[cand.effect] and _lamp_frames_hold(chosen, again_cand, y.shape[0]):
            return cand
    return None


def _lamp_frames_hold(chosen: Candidate, lamp: Candidate, n_frames: int) -> bool:
    """Whether the lamp-lit frames still found with a patch change or shadow modelled are where it was (its onset
    on, the shaded frames): lamp light explains such an effect only in the frames the effect shows in. Other effects,
    or a candidate that is not off-locus light: ``True``. (A development history shaded at frames 2–5, ΔBIC −5 406:
    with the shaded values dropped, two other daylight frames passed the off-locus margin by 0.3 and the shadow was
    put down to lamp light.)"""
    if lamp.effect != "off_locus_illuminant" or chosen.effect not in ("patch_change", "shadow"):
        return True
    found = set(lamp.parameters.get("frame_indices") or ())
    prm = chosen.parameters
    if chosen.effect == "shadow" and "first_frame_index" in prm:
        where = set(range(int(prm["first_frame_index"]), int(prm["last_frame_index"]) + 1))
    elif chosen.frame is not None:
        where = set(range(int(chosen.frame), n_frames))
    else:
        return True
    return bool(found & where)


@single_blas_thread
def diagnose(
    obs: Observations,
    sensitivities: NDArray[np.float64],
    *,
    rank: int = RANK,
    reestimate: bool = True,
    margins: dict[str, float] | None = None,
    learn_noise: bool = True,
    from_images: bool | None = None,
    white_level: float | None = None,
    primaries: str = "camera",
) -> Diagnosis:
    """Name the effect that breaks the linear model in a history, where it is, and what modelling it changes.

    Parameters
    ----------
    obs
        Observations (values on a 0…1 scale, NaN where missing), at least :data:`SHORT_HISTORY_FRAMES` frames; a
        history shorter than ``rank + 2`` is judged for its light alone (:func:`_short_history`).
    sensitivities
        Camera sensitivities on the grid (61 × 3).
    rank
        Rank of the bilinear model.
    reestimate
        Re-estimate the illuminants with the chosen extension and report the change (two joint fits).
    margins
        ΔBIC margins per effect (default :data:`NONE_MARGIN`).
    learn_noise
        Learn the noise from the history's residuals (:func:`.bilinear.estimate_noise`); ``False`` assumes the
        noise of :data:`illumon.camera.DEFAULT_NOISE` (the former method, kept for comparison).
    from_images
        Whether the values were measured from images by the service's robust region means; default: when ``obs.sd``
        (the standard errors it measures) is present. Such values may carry output-domain noise (a codec's:
        :data:`.noise.CODEC_NOISE`) beside the noise of linear light, and a region they leave out was more than half
        clipped (:func:`.stages._censored_at_ingest`).
    white_level
        The white level the values were divided by (their codes), if known: values within
        :data:`.noise.DARK_CODES` codes of black are censored at any brightness; above that, a dim history's censoring
        level follows its own brightness (:func:`.noise.history_dark_level`).
    primaries
        The camera's output space (:data:`illumon.camera.primaries.PRIMARIES`). A history lit by lamps throughout is
        named ``off_locus_illuminant`` when the estimator's common level judges it so (:func:`_lamp_lit_history`):
        for rendered output (``"srgb"``: white balance and a colour matrix) against the balance, for sensor RGB
        (``"camera"``) against the daylight whites through the sensitivities given and through a camera nobody
        measured, both (:func:`_sensor_rgb_verdict`).

    Returns
    -------
    Diagnosis
    """
    margins = {**NONE_MARGIN, **(margins or {})}
    f, p, _ = obs.values.shape
    if f < min_frames(primaries, rank):
        raise ValueError(f"diagnosis needs at least {rank + 2} frames, got {f}" + short_history_hint(primaries))
    if p < 3:
        raise ValueError(f"diagnosis needs at least 3 patches, got {p}")
    with dark_level_set(history_dark_level(obs.values, white_level)):
        if f < rank + 2:
            return _short_history(obs, sensitivities, rank, reestimate, primaries)
        return _diagnose(obs, sensitivities, rank, reestimate, margins, learn_noise, from_images, primaries)


SHORT_HISTORY_FRAMES = 1
"""Fewest frames whose light is judged as a whole when the history is too short for the bilinear effects
(:func:`_short_history`)."""


def min_frames(primaries: str, rank: int = RANK) -> int:
    """The fewest frames :func:`diagnose` accepts: :data:`SHORT_HISTORY_FRAMES`, below ``rank + 2`` (the bilinear
    effects' fewest) the history's light being judged alone (:func:`_lamp_lit_history`), for either primaries.
    ``rank`` is kept for the callers' signature."""
    check_primaries(primaries)
    return SHORT_HISTORY_FRAMES


def short_history_hint(primaries: str) -> str:
    """What a refused short history could do instead, to follow "needs at least ``rank + 2`` frames"."""
    check_primaries(primaries)
    return f" ({SHORT_HISTORY_FRAMES} to judge its light alone)"


def _short_history(obs: Observations, css: NDArray[np.float64], rank: int, reestimate: bool,
                   primaries: str) -> Diagnosis:
    """A history too short for the bilinear effects (fewer than ``rank + 2`` frames) judged for its light alone.

    The bilinear stage fits a rank-``rank`` model of the frames and needs two frames more than its rank to leave any
    residual to read an effect in (tone curve, clipping, pedestal, patch change, shadow, fluorescence). Whether the
    history is lit by lamps throughout is a judgement of the scene model's common level, not of residuals
    (:func:`_lamp_lit_history`), and holds on a few frames (the real MIMO lamp-lit scenes have three to six). Such a
    history gets that verdict only: ``off_locus_illuminant`` with its frames, or ``none``; a note says the other
    effects were not judged, and ``residual_base`` / ``residual_extended`` are ``None`` (no bilinear fit)."""
    f = len(obs.frames)
    css = np.asarray(css, dtype=float)
    lamp = _lamp_lit_history(obs, css, [], primaries)
    found = [lamp] if lamp is not None else []
    base = Diagnosis("none", None, None, {}, [], None, None, 0.0, info={"score": np.nan})
    if found and reestimate:
        _illuminant_changes(obs if f > 1 else obs.subset([0, 0]), css, found)  # one frame: given twice (the joint
        # retrieval's fewest; the same view under the same light), the lamp whites against the first
    out = _ranked(obs, base, found, reestimate)
    out.residual_base = out.residual_extended = None  # the lamp verdict's too, when it is the one reported
    out.notes.append(f"only {f} frame{'s' if f > 1 else ''}: the history's light was judged as a whole; the other "
                     f"effects need at least {rank + 2} frames")
    out.info["censoring_level"] = round(dark_level(), 6)
    return out


def _diagnose(obs: Observations, sensitivities: NDArray[np.float64], rank: int, reestimate: bool,
              margins: dict[str, float], learn_noise: bool, from_images: bool | None,
              primaries: str = "camera") -> Diagnosis:
    """:func:`diagnose` at the history's censoring level."""
    css = np.asarray(sensitivities, dtype=float)
    images = obs.sd is not None if from_images is None else bool(from_images)
    chosen, cands, info = _choose(obs, css, rank, margins, learn_noise, from_images=images)
    diag = _as_diagnosis(obs, chosen, cands, info)
    found = _further_effects(obs, css, rank, margins, learn_noise, [diag] if chosen is not None else [], images)
    lamp = _lamp_lit_history(obs, css, found, primaries)
    if lamp is not None:
        found = [d for d in found if d.effect != "off_locus_illuminant"] + [lamp]
    if reestimate:
        if not found:
            diag.illuminant_change_deg = 0.0
        else:
            _illuminant_changes(obs, sensitivities, found)
    else:  # a few values at the white level are a note or an effect by what modelling them changes, re-estimated or not
        minor = [d for d in found if _few_clipped(obs, d)]
        if minor:
            _illuminant_changes(obs, sensitivities, minor)
    out = _ranked(obs, diag, found, reestimate)
    out.info["censoring_level"] = round(dark_level(), 6)
    return out


def _lamp_lit_history(obs: Observations, css: NDArray[np.float64], found: list[Diagnosis],
                      primaries: str) -> Diagnosis | None:
    """Light that is not daylight over the whole history, or None.

    The spectral stage finds lamp-lit frames as outliers of the history's own frames (:func:`.spectral.off_locus_gains`
    in units of its typical frame), so a history lit by lamps *throughout* has none: its typical frame is lamp-lit (the
    real MIMO lamp-lit scenes, every frame a pair of white, red or blue lamps: lamp light named in 2 of 6 frames of
    one development scene, ``none`` for the other). The estimator's scene model judges such a history as a whole
    (:func:`illumon.model.level.common_level_posterior`), and each frame's ``non_daylight`` follows
    (:func:`illumon.model.lamps.apply_lamps`): for rendered output the camera's balance places a daylight history's
    mean white near grey, a lamp-lit one's near a lamp's; for sensor RGB the scene average is placed among the
    daylight or the lamps' whites through the camera given and through a camera nobody measured, both of which must
    say lamps (:func:`_sensor_rgb_verdict`). When the history is more
    likely lamp-lit than not, the effect is named with the frames whose ``non_daylight`` ≥ 0.5 (at least
    :data:`MIN_OFF_LOCUS_FRAMES`; those the spectral stage found are kept too). ``lamp_share`` is the share of lamp
    light re-fitted as in the spectral stage (:func:`.spectral.lamp_shares`) where at least two daylight frames remain
    to learn the reflectances from, else ``None`` (not estimable: no daylight frame). The verdict is judged with the
    global effects found modelled (values linearised, offsets subtracted, clipped values dropped: a tone curve pulls
    the scene's average towards grey, a pedestal towards its own colour), the rule that a spectral effect is named
    beside a global one only when it survives the other modelled; the global effects keep their own (bilinear)
    evidence, which lamps lighting every frame cannot explain away (no frame is left to fit without them). Score:
    ``−2 ln`` of the posterior odds. What modelling it changes (``illuminant_change_deg``) is the move from the
    daylight-only joint estimate to the scene model's whites, which follow the lamps (``info["lamp_whites"]``).
    A history judged daylight as a whole may still have lamp-lit frames (:func:`_lamp_lit_frames`)."""
    judged = obs
    for d in found:
        if d.effect in GLOBAL_EFFECTS:
            judged = corrected_observations(judged, d)
    verdict = _level_verdict(judged, css, primaries)
    if check_primaries(primaries) == "camera":
        verdict = _sensor_rgb_verdict(verdict, _level_verdict(judged, None, primaries), judged)
    if verdict is None:
        return None
    model, p, nd = verdict
    spectral = next((d for d in found if d.effect == "off_locus_illuminant"), None)
    if p <= 0.5:
        return None if spectral is not None else _lamp_lit_frames(obs, css, nd)
    frames = set(np.flatnonzero(nd >= 0.5).tolist())
    if spectral is not None:
        frames |= set(spectral.parameters.get("frame_indices", []))
    idx = sorted(int(i) for i in frames)
    if len(idx) < min(MIN_OFF_LOCUS_FRAMES, len(obs.frames)):  # a single frame lit by lamps is the whole history
        return None
    score = -2.0 * float(np.log(min(p, 1 - 1e-12) / max(1.0 - p, 1e-12)))
    params = {"frame_indices": idx, "frames": [obs.frames[i] for i in idx],
              "non_daylight": [round(float(nd[i]), 3) for i in idx], "history_non_daylight": round(p, 4),
              "lamp_share": _lamp_share_column(obs, css, idx), "found_by": "scene_level"}
    if spectral is not None:
        params["spectral_frames"] = list(spectral.parameters.get("frames", []))
    return Diagnosis("off_locus_illuminant", None, None, params, [], 0.0, 0.0, None,
                     info={"score": score, "rms_base": 0.0,
                           "lamp_whites": np.asarray(model.history_estimate[0].white, dtype=float)})


Verdict = tuple["SceneModel", float, NDArray[np.float64]]
"""A scene model, the posterior probability that its history is lit by lamps throughout, each frame's
``non_daylight`` (:func:`_level_verdict`)."""


def _level_verdict(obs: Observations, css: NDArray[np.float64] | None, primaries: str
                   ) -> Verdict | None:
    """The estimator's scene model of ``obs`` (:func:`illumon.model.fit_scene_model`, ``css`` None for a camera nobody
    measured), the posterior probability that the history is lit by lamps throughout (``noise["unbalanced"]``,
    :func:`illumon.model.level.common_level_posterior`) and every frame's ``non_daylight``; None where the model
    cannot be fitted."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            model = fit_scene_model(obs, css, primaries=primaries)
    except (ValueError, np.linalg.LinAlgError):
        return None
    if model.history_estimate is None:
        return None
    nd = np.asarray(model.history_estimate[1].get("non_daylight", []), dtype=float)
    if nd.shape != (len(obs.frames),):
        return None
    return model, unbalanced_probability(model), nd


def _sensor_rgb_verdict(given: Verdict | None, unmeasured: Verdict | None, obs: Observations) -> Verdict | None:
    """Sensor RGB's whole-history verdict from two level tests of the estimator (:mod:`illumon.model.level`): with the
    sensitivities given, as a measured camera's (its daylight whites ± 0.02), and as a camera nobody measured (the
    scene average against the daylight and the CIE lamps' whites through the measured cameras' mean, each within their
    spread: the estimator's test for ``--primaries camera`` without sensitivities). The diagnosis cannot tell measured
    sensitivities from stand-ins (the sRGB functions outside checkers pass for a camera nobody measured), and each
    test fails where the other holds:

    * given stand-ins, the measured camera's test calls real photographs lamp-lit that both tests otherwise read as near
      daylight (``sony-raw``, indoor, light unknown, with the mean measured
      camera 0.99; ``benchmarks/unmeasured.py``'s raw daylight histories given the clipped sRGB functions, development
      seeds 3 000–3 013, both simulators: ``pale`` 26 of 28 above 0.5, every frame judged lamp-lit, ``none`` 20 of
      28), where the unmeasured camera's says 0.00 on all but the Point Grey camera's ``pale`` ones (below);
    * a measured camera whose daylight white lies outside the measured cameras' spread (the Point Grey machine-vision
      camera) reads lamp-lit to the unmeasured test on a daylight scene of pale surfaces (0.93), not to its own (0.00).

    So the history is lamp-lit throughout when both say so (probability the smaller of the two; the frames as the
    unmeasured test judges them: on a history lit by lamps throughout it judged every frame lamp-lit where it judged
    the history so, the measured test 16–24 of 30). The real MIMO lamp-lit scenes (development) given the clipped sRGB
    functions: 0.997 and 0.95–0.97. Otherwise (the probability of the test that found the history daylight) a frame
    is lamp-lit, for :func:`_lamp_lit_frames`, when both tests judge it so on its own against their history's
    scene-average offset (:func:`illumon.model.lamps.frame_verdicts`: the smaller ``non_daylight``; a test that found
    the history lamp-lit as a whole would otherwise lend every frame that probability). The frames of one test alone
    fail as the histories do: output a raw converter rendered, read as sensor RGB (what the MIMO scenes are) through
    the clipped sRGB functions — whose daylight locus is compressed (log r/g moves 0.20 from 11 000 to 5 600 K, 0.34
    through the unclipped functions) — reads a day's sky changes as lamps (``benchmarks/short_histories.py
    --primaries camera --rendered``). None where either model cannot be fitted."""
    if given is None or unmeasured is None:
        return None
    if given[1] > 0.5 and unmeasured[1] > 0.5:
        return unmeasured[0], min(given[1], unmeasured[1]), unmeasured[2]
    model, p, _ = given if given[1] <= 0.5 else unmeasured
    each = []
    for verdict in (given, unmeasured):
        own = frame_verdicts(verdict[0], obs)
        each.append(verdict[2] if own is None else own)
    return model, p, np.minimum(each[0], each[1])


def _lamp_share_column(obs: Observations, css: NDArray[np.float64], idx: list[int]) -> list[float | None]:
    """``lamp_share`` of the lamp-lit frames ``idx`` (rounded), re-fitted as in the spectral stage
    (:func:`.spectral.lamp_shares`, reflectances learned from the other frames) where at least two of those remain,
    else ``None`` each (not estimable)."""
    shares: list[float | None] = [None] * len(idx)
    if len(obs.frames) - len(idx) >= 2:
        try:
            shares = lamp_shares(refined_spectral_base(obs, css), idx, sigma=daylight_reflectances(obs, css, idx))
        except (ValueError, np.linalg.LinAlgError):
            pass
    return [None if v is None else round(float(v), 2) for v in shares]


LAMP_FRAMES_SHARE = 0.1
"""Share of a history's frames (at least :data:`MIN_OFF_LOCUS_FRAMES`) that the scene model must judge lamp-lit
(``non_daylight`` ≥ 0.5) before :func:`_lamp_lit_frames` names off-locus light the spectral stage missed. Chosen on the
development split (``python benchmarks/lamp_majority.py``; ``benchmarks/diagnose.py --split dev``): the clean, tone,
offset, patch-change, shadow and fluorescence histories had at most 2 such frames (of 24–40)."""


def _lamp_lit_frames(obs: Observations, css: NDArray[np.float64], nd: NDArray[np.float64]) -> Diagnosis | None:
    """Off-locus light in frames the scene model judges lamp-lit, when the spectral stage named none, or None.

    The spectral stage measures each frame's misfit in units of the history's *typical* frame, so lamps that light
    most of the frames (a scene lit by lamps most of the time: two thirds of the frames mixed 35–80 % with a lamp)
    make the typical frame lamp-lit and leave no outlier — the outside check's 0 of 2, 1 of 10 development histories
    (``benchmarks/lamp_majority.py``). The scene model's ``non_daylight`` (:mod:`illumon.model.lamps`) judges each
    frame's scene-average colour against daylight and lamp whites with the scene's own average integrated out; the
    daylight frames pin that average, however few. At least :data:`LAMP_FRAMES_SHARE` of the frames judged lamp-lit
    name the effect (``found_by: frames``); score: ``−2 Σ ln`` of their posterior odds; ``lamp_share`` as in the
    spectral stage where two daylight frames remain."""
    idx = [int(i) for i in np.flatnonzero(nd >= 0.5)]
    if len(idx) < max(MIN_OFF_LOCUS_FRAMES, int(np.ceil(LAMP_FRAMES_SHARE * len(obs.frames)))):
        return None
    odds = np.clip(nd[idx], 1e-12, 1 - 1e-12)
    score = -2.0 * float(np.sum(np.log(odds / (1.0 - odds))))
    params = {"frame_indices": idx, "frames": [obs.frames[i] for i in idx],
              "non_daylight": [round(float(nd[i]), 3) for i in idx],
              "lamp_share": _lamp_share_column(obs, css, idx), "found_by": "frames"}
    return Diagnosis("off_locus_illuminant", None, obs.frames[idx[0]], params, [], 0.0, 0.0, None,
                     frame_index=idx[0], info={"score": score, "rms_base": 0.0})


def _few_clipped(obs: Observations, d: Diagnosis) -> bool:
    """Clipping of at most :data:`MINOR_CLIPPING_FRACTION` of the history's values (a note if it changes little)."""
    return d.effect == "clipping" and d.parameters.get("clipped_values", 0) <= MINOR_CLIPPING_FRACTION * obs.values.size


def _further_effects(obs: Observations, css: NDArray[np.float64], rank: int, margins: dict[str, float],
                     learn_noise: bool, found: list[Diagnosis], from_images: bool = False) -> list[Diagnosis]:
    """Several effects at once (a history may carry more than one): model the one found, look again in what is left, until nothing
    passes its margin (at most :data:`MAX_EFFECTS`); every effect in the original history's indices."""
    current = obs
    structural = np.zeros(obs.values.shape, dtype=bool)
    while found and len(found) < MAX_EFFECTS:
        previous, current = current, _modelled(current, found[-1])
        if current is None or current.values.shape[0] < rank + 2 or current.values.shape[1] < 3:
            break
        structural = _structural(previous, current, structural)
        nxt, ncands, ninfo = _choose(current, css, rank, margins, learn_noise,
                                     exclude={d.effect for d in found}, from_images=from_images,
                                     structural=structural)
        if nxt is None:
            break
        found.append(_as_diagnosis(current, nxt, ncands, ninfo))
    # every effect in the original history's indices (a later one was found with earlier ones modelled)
    return [d if i == 0 else (_on_original(obs, d) or d) for i, d in enumerate(found)]


def _structural(previous: Observations, current: Observations, mask: NDArray[np.bool_]) -> NDArray[np.bool_]:
    """Values of ``current`` (``previous`` with an effect modelled) missing because of the modelling, with those
    ``mask`` marks in ``previous``: dropped values, and the part of a split patch before or after its onset."""
    rows = [previous.frames.index(fr) for fr in current.frames]
    gone = np.isnan(current.values)
    out = np.zeros(current.values.shape, dtype=bool)
    for j, name in enumerate(current.patches):
        if name in previous.patches:
            k = previous.patches.index(name)
            out[:, j] = mask[rows, k] | (gone[:, j] & np.isfinite(previous.values[rows, k]))
        else:  # the part of a split patch: missing where the other part is
            out[:, j] = gone[:, j]
    return out


def _illuminant_changes(obs: Observations, sensitivities: NDArray[np.float64], found: list[Diagnosis]) -> None:
    """Each effect re-estimated on its own, to rank them by what they change: ``illuminant_change_deg`` (the median
    angular change of the camera white) and the two estimates in ``info``, set on every diagnosis in place."""
    fast = {"start_offsets": (0.0,), "polish_max_frames": 0}
    before = retrieve_illuminants(obs, sensitivities, **fast)
    for i, d in enumerate(found):
        if i > 0 and d.patch is not None and d.patch not in obs.patches:
            continue  # a part of a split patch: its change is not defined on the original history
        if d.parameters.get("found_by") == "scene_level":  # lamps throughout: the scene model's whites follow them
            after = copy.deepcopy(before)
            after.white = np.resize(d.info["lamp_whites"], before.white.shape)  # a single frame's given twice
        else:
            after = estimate_with_effect(obs, sensitivities, d, base_result=before, **fast)
        d.illuminant_change_deg = round(float(np.median(angular_error_deg(before.white, after.white))), 4)
        d.info["before"], d.info["after"] = before, after


def _ranked(obs: Observations, diag: Diagnosis, found: list[Diagnosis], reestimate: bool) -> Diagnosis:
    """The reported diagnosis: minor clipping turned into notes, the effects most consequential first (when
    re-estimated), the first one's diagnosis carrying the first round's candidates and every effect's entry."""
    effects, notes = [], []
    for d in found:
        score = float(d.info.get("score", np.nan))
        entry = {"effect": d.effect, "patch": d.patch, "frame": d.frame, "parameters": d.parameters,
                 "score": round(score, 3) if np.isfinite(score) else None,
                 "illuminant_change_deg": d.illuminant_change_deg}
        if (_few_clipped(obs, d) and d.illuminant_change_deg is not None
                and d.illuminant_change_deg <= MINOR_CLIPPING_DEG):
            notes.append(f"{d.parameters.get('clipped_values')} values at the white level "
                         f"({d.parameters.get('clip_level')}), censored anyway; modelling them moves the "
                         f"illuminants by {d.illuminant_change_deg}° (a note, not an effect)")
            continue
        effects.append((d, entry))
    if reestimate:  # most consequential first
        effects.sort(key=lambda de: -(de[0].illuminant_change_deg if de[0].illuminant_change_deg is not None else -1.0))
    if effects and effects[0][0] is not diag:
        first = effects[0][0]
        first.candidates = diag.candidates
        first.residual_base = diag.residual_base
        diag = first
    elif not effects and found:  # only notes: the history is clean
        diag = _as_diagnosis(obs, None, diag.candidates, {**diag.info, "rms_base": diag.residual_base})
        diag.illuminant_change_deg = 0.0
    diag.effects = [e for _, e in effects]
    diag.notes = notes
    order = {id(d): i for i, d in enumerate(found)}
    diag.info["found"] = [d for d, _ in sorted(effects, key=lambda de: order[id(de[0])])]  # discovery order
    return diag


MAX_EFFECTS = 3
"""At most this many effects are reported for one history."""

MINOR_CLIPPING_DEG = 0.1
"""Clipping that moves the median illuminant by no more than this (degrees) is a note, not an effect (a few
values at the white level, censored by every fit anyway)."""


def _choose(obs: Observations, css: NDArray[np.float64], rank: int, margins: dict[str, float], learn_noise: bool,
            exclude: set[str] | frozenset = frozenset(), from_images: bool = False,
            structural: NDArray[np.bool_] | None = None) -> tuple[Candidate | None, list[Candidate], dict]:
    """One round of selection (module docstring): the bilinear stage, the spectral stage, the converse checks."""
    f, p, _ = obs.values.shape
    y = obs.values.reshape(f, 3 * p)
    _, cands, info = bilinear_stage(y, rank, margins["clipping"], learn_noise, *_image_noise(from_images),
                                    None if structural is None else structural.reshape(f, 3 * p),
                                    _image_se(obs, from_images))
    spectral, sinfo = spectral_stage(obs, css, margins["fluorescence"])
    info.update(sinfo)
    cands += spectral
    for c in cands:
        if c.patch is not None:
            c.parameters["patch"] = obs.patches[c.patch]
        if c.frame is not None and c.effect in ("patch_change", "shadow"):
            c.parameters["frame"] = obs.frames[c.frame]
    chosen: Candidate | None = None
    bil = [c for c in cands if c.effect not in ("off_locus_illuminant", "fluorescence") and c.effect not in exclude]
    ok = [c for c in bil if supported(c, margins[c.effect])]
    spectral_ok = [c for c in spectral if c.effect not in exclude]
    if ok:
        chosen = min(ok, key=lambda c: c.score)
        chosen = _spectral_cause(obs, css, rank, chosen, spectral_ok, margins, learn_noise, from_images) or chosen
    else:
        # off-locus frames first: their misfit can make a patch look fluorescent, not the reverse
        ok = [c for c in spectral_ok if c.score < -margins[c.effect]]
        if ok:
            chosen = ok[0]
            if chosen.effect == "off_locus_illuminant" and "black_offset" not in exclude:
                chosen = _pedestal_cause(obs, css, chosen, margins) or chosen
    return chosen, cands, info


def _pedestal_cause(obs: Observations, css: NDArray[np.float64], lamp: Candidate,
                    margins: dict[str, float]) -> Candidate | None:
    """A black offset that explains what the spectral stage took for lamp light, or None.

    An auto-exposure that keeps the scene's mean brightness steady leaves a pedestal invisible to the bilinear model
    (one combination of its frame factors is constant and carries it), while the spectral model, whose reflectances
    cannot add the same signal under every light, misfits it as light off the daylight locus: 2…6 % pedestals of
    the image-based simulator's development histories scored ΔBIC +10…+21 as offsets and −66…−152 as lamp light, and
    subtracting the true pedestal left the lamp at −1…+2. The pedestal is fitted within the spectral model
    (:func:`.spectral.spectral_pedestal`) and named when it passes the offset's margin (its cost drop read as
    ``−2·ΔNLL``, three parameters), is at least :data:`.stages.MIN_OFFSET` and allowed by the values
    (:func:`.stages.pedestal_allowed`), the lamp no longer passes its margin with it subtracted, and it survives the
    lamp modelled (fitted again without the lamp-lit frames) — the rule that a global effect and a spectral one
    explain each other only when each survives the other modelled.
    """
    y = obs.values.reshape(obs.values.shape[0], -1)

    def pedestal(o: Observations) -> tuple[NDArray[np.float64], float]:
        base = refined_spectral_base(o, css)
        b, gain = spectral_pedestal(base)
        return b, -gain + 3.0 * np.log(max(int(base.prob.present.sum()) * 3, 2))

    def passes(b: NDArray[np.float64], score: float) -> bool:
        return bool(score < -margins["black_offset"] and np.max(b) >= MIN_OFFSET)

    try:
        b, score = pedestal(obs)
        if not (passes(b, score) and pedestal_allowed(y, np.isfinite(y), b)):
            return None
        corrected = Observations(list(obs.frames), list(obs.patches), np.clip(obs.values - b, 1e-6, None),
                                 list(obs.times), obs.sd)
        again, _ = spectral_stage(corrected, css, margins["fluorescence"])
        if next(c.score for c in again if c.effect == lamp.effect) < -margins[lamp.effect]:
            return None
        keep = np.setdiff1d(np.arange(len(obs.frames)), lamp.parameters["frame_indices"])
        if keep.size >= 6 and not passes(*pedestal(obs.subset(keep))):
            return None
    except (ValueError, np.linalg.LinAlgError):
        return None
    return Candidate("black_offset", float(score), {"offsets": [round(float(v), 5) for v in b],
                                                    "found_by": "spectral"})


def _image_noise(from_images: bool) -> tuple[float, bool]:
    """The bilinear stage's ``codec_cap`` and ``unseen_clipped`` for values measured from images or not."""
    return (CODEC_NOISE, True) if from_images else (0.0, False)


def _image_se(obs: Observations, from_images: bool) -> NDArray[np.float64] | None:
    """The standard errors of values measured from images, frames × (patches·channels), for the clip-level test
    (:func:`.stages._saturated`); None otherwise or when the history has none."""
    if not from_images or obs.sd is None:
        return None
    sd = np.asarray(obs.sd, dtype=float)
    return sd.reshape(sd.shape[0], -1) if sd.shape == obs.values.shape else None


def _as_diagnosis(obs: Observations, chosen: Candidate | None, cands: list[Candidate], info: dict) -> Diagnosis:
    """A :class:`Diagnosis` of ``obs`` for the chosen candidate (``none`` without one)."""
    effect = chosen.effect if chosen else "none"
    params = dict(chosen.parameters) if chosen else {}
    patch_i = chosen.patch if chosen and effect in ("patch_change", "shadow", "fluorescence") else None
    frame_i = chosen.frame if chosen and effect in ("patch_change", "shadow") else None
    if effect == "off_locus_illuminant":
        params["frames"] = [obs.frames[i] for i in params["frame_indices"]]
    if effect == "shadow":
        params["shaded_frames"] = [obs.frames[i] for i in range(params["first_frame_index"], params["last_frame_index"] + 1)]
    return Diagnosis(
        effect=effect,
        patch=obs.patches[patch_i] if patch_i is not None else None,
        frame=obs.frames[frame_i] if frame_i is not None else None,
        parameters=params,
        candidates=cands,
        residual_base=round(info["rms_base"], 4),
        residual_extended=round(chosen.residual, 4) if chosen and chosen.residual is not None else round(info["rms_base"], 4),
        illuminant_change_deg=None,
        patch_index=patch_i,
        frame_index=frame_i,
        info={**{k: v for k, v in info.items() if k != "fits"}, "score": chosen.score if chosen else np.nan},
    )


def _modelled(obs: Observations, diag: Diagnosis) -> Observations | None:
    """``obs`` with ``diag``'s effect modelled out, for the next round: :func:`corrected_observations`, and the
    off-locus frames left out."""
    if diag.effect == "off_locus_illuminant":
        keep = np.setdiff1d(np.arange(len(obs.frames)), diag.parameters.get("frame_indices", []))
        return obs.subset(keep) if keep.size else None
    return corrected_observations(obs, diag)


def _on_original(obs: Observations, d: Diagnosis) -> Diagnosis | None:
    """``d`` (found on a history with earlier effects modelled) with its patch and frame indices in ``obs``; ``None``
    when its patch is not one of ``obs``'s (a split patch)."""
    out = copy.copy(d)
    out.parameters = dict(d.parameters)
    if d.patch is not None:
        if d.patch not in obs.patches:
            return None
        out.patch_index = obs.patches.index(d.patch)
    if d.frame is not None:
        out.frame_index = obs.frames.index(d.frame)
    if d.effect == "off_locus_illuminant":
        out.parameters["frame_indices"] = [obs.frames.index(fr) for fr in d.parameters["frames"]]
    if d.effect == "shadow":
        idx = [obs.frames.index(fr) for fr in d.parameters["shaded_frames"]]
        out.parameters["first_frame_index"], out.parameters["last_frame_index"] = min(idx), max(idx)
    return out
