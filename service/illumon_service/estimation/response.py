"""The check of a camera's declared tone response against its stored history (the diagnosis's tone-curve test)."""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import Any

import numpy as np
from illumon._blas import single_blas_thread
from illumon.diagnosis.candidate import NONE_MARGIN, RANK  # not .fit: the whole diagnosis's imports
from illumon.diagnosis.noise import CODEC_NOISE
from illumon.diagnosis.stages import tone_stage
from illumon.observations import Observations
from numpy.typing import NDArray

from .history import build_observations, seen_patches

__all__ = ["RESPONSE_CHECK_FRAMES", "check_response"]

log = logging.getLogger("illumon_service.estimation")


RESPONSE_CHECK_FRAMES = 48
"""Frames (spread evenly over the history) the tone-response check diagnoses; ~2 s on 48 frames × 8 regions."""


def check_response(
    frames: Sequence[tuple[str, str, dict[str, Any]]] | Observations,
    region_ids: Sequence[str],
    sensitivities: NDArray[np.float64] | None,
    encoding: str,
    max_frames: int = RESPONSE_CHECK_FRAMES,
) -> dict:
    """Does the stored history (values linearised with the declared response) still look non-linear?

    Runs the diagnosis's tone-curve test (:func:`illumon.diagnosis.stages.tone_stage`, the bilinear stage's test:
    the history is fitted as ``y = x^(1/γ)`` of a rank-4 linear model and γ is accepted by ΔBIC, Schwarz 1978) on at
    most ``max_frames`` frames spread evenly over the history. When the tone curve beats the linear model by the
    diagnosis's own margin (ΔBIC < −25, :data:`illumon.diagnosis.fit.NONE_MARGIN`) — whichever effect the whole
    diagnosis would finally name: an sRGB curve read as linear also fits as a *negative* black offset, often better —
    the declared ``encoding`` does not match what the camera sends: γ > 1 means the values are still tone-encoded
    (a camera sending sRGB declared ``linear``), γ < 1 that they were linearised once too often.

    Only the tone-curve test runs, not the whole diagnosis: its candidate is the one the whole diagnosis computes, so
    the verdict is the same, at a fifth of the cost (the other extensions and the spectral stage took ~60 % of a
    2k-frame refit). And it runs only until its verdict against that margin is settled (``decide``,
    :func:`illumon.diagnosis.tone.tone_candidate`: the same verdict and γ — on 576 development histories of every
    effect, with and without the codec's noise — with 6 noise-learning fits of a linear history's check where the
    whole test made 15–18; the refit benchmark's check 0.24 → 0.10–0.14 s), so ``tone_score`` is the best score the
    test reached by then, on the same side of the margin as the whole test's: for a tone curve no lower than it (the
    refit benchmark's tone-encoded checks −134…−267 → −95…−176), for none at most γ = 1's ``log n`` (its linear ones
    +0.7…+7.9 → +6.8…+7.6).
    The test is camera-agnostic: ``sensitivities`` are not used. ``frames``: history rows
    (:func:`~.history.history_row`) or their observations (:func:`~.history.build_observations`).

    Returns
    -------
    dict
        ``{"checked", "effect"`` (``nonlinear_response`` when the tone curve is supported, else ``none``; refits
        that ran the whole diagnosis stored its answer), ``"tone_score"`` (ΔBIC of the tone curve, as above), ``"gamma"``
        (when the tone curve is supported), ``"warnings": [str, ...], "reason"}``;
        ``checked`` is false (and ``reason`` says why) when the history is too short (the test needs 6 frames
        and 3 regions) or the test fails.
    """
    obs = frames if isinstance(frames, Observations) else build_observations(frames, region_ids)
    keep = np.flatnonzero(obs.present.sum(axis=1) >= 3)
    if keep.size > max_frames:
        keep = keep[np.round(np.linspace(0, keep.size - 1, max_frames)).astype(int)]
    out: dict[str, Any] = {"checked": False, "effect": None, "gamma": None, "warnings": [], "reason": ""}
    if keep.size < RANK + 2 or len(region_ids) < 3:
        out["reason"] = f"tone response not checked: needs {RANK + 2} frames with 3 regions seen, {keep.size} stored"
        return out
    obs = seen_patches(obs.subset(keep))
    try:
        f, p, _ = obs.values.shape
        if p < 3:  # as the diagnosis requires
            raise ValueError(f"diagnosis needs at least 3 patches, got {p}")
        # region means measured from images (with their standard errors) may carry a codec's noise, as in the diagnosis
        codec = CODEC_NOISE if obs.sd is not None else 0.0
        tone, _ = single_blas_thread(tone_stage)(obs.values.reshape(f, 3 * p), RANK, True, codec,
                                                 NONE_MARGIN["nonlinear_response"])
    except Exception as exc:  # noqa: BLE001 - a check that cannot run must not fail the refit
        log.warning("tone-response check failed: %s", exc)
        out["reason"] = f"tone response not checked: {exc}"
        return out
    supported = tone.score < -NONE_MARGIN["nonlinear_response"]
    out.update(checked=True, effect="nonlinear_response" if supported else "none",
               tone_score=round(float(tone.score), 1))
    if supported:
        g = float(tone.parameters["gamma"])
        out["gamma"] = g
        if g > 1:
            hint = (f"the frames still look tone-encoded (values ≈ linear^(1/{g:.2f})) although the camera is declared "
                    f"'{encoding}': most cameras send sRGB-encoded JPEG; register it with response encoding 'srgb' (or "
                    "'gamma'), else every estimate is off")
        else:
            hint = (f"the frames look linearised twice (values ≈ linear^(1/{g:.2f})) with the declared response '{encoding}': "
                    "the camera probably sends linear (raw) values; declare response encoding 'linear'")
        out["warnings"].append(hint)
    return out
