"""The effects that break the linear model of a fixed camera, and a generator that hides one in a simulated history.

Effect names are the contract of ``illumon diagnose`` (:data:`EFFECTS`). :func:`hide_effect` renders a history from a
measured camera, a run of measured Granada daylight and measured reflectances (:func:`illumon.priors.unseen_reflectances`),
adds one effect with seeded random parameters in realistic ranges, then auto-exposure jitter, shot and read noise
(:class:`illumon.camera.noise.CameraNoise`) and the camera's response. Tests and benchmarks share it.

Physical models of the effects (what the generator renders and what :mod:`illumon.diagnosis.fit` fits):

``nonlinear_response``
    encoded = linear^(1/γ) (a gamma tone curve, :class:`illumon.camera.ResponseCurve` ``"gamma"``), γ ∈ [1.5, 2.6].
``black_offset``
    encoded = linear + b_c, a pedestal per channel, b_c ∈ [0.015, 0.06] of the white level.
``clipping``
    the metering targets a brighter level (1.05…1.4 of the white level for the brightest patch), values saturate at 1.
``patch_change``
    from an onset frame on, one patch has a new reflectance: another measured surface (repainted, replaced) or the old
    one darkened and yellowed by dirt (soiled).
``shadow``
    one patch is lit for a run of frames by skylight only: a CIE daylight of 10 000…25 000 K at 15…45 % of the frame's
    daylight level at 560 nm. The run ends inside the history (a shadow that lasts to the end is a patch change).
``off_locus_illuminant``
    3…F/5 frames are lit by a mix of a CIE fluorescent, LED or high-pressure lamp far from daylight (CCT ≤ 4250 K or
    Duv ≥ 0.009; 60…100 % of the light) and daylight.
``fluorescence``
    one patch adds emission ``s · (Σλ' a(λ') E(λ')) · e(λ)`` (Han et al., CVPR 2012, eqs. 1–2) with the excitation
    ``a`` and emission ``e`` of a fluorophore from the McNamara & Boswell compilation (any of the ~370 with a
    short-wave excitation, visible peak < 600 nm, :data:`SHORT_WAVE_EXCITATION_NM`; the detection assumes none);
    the emitted signal is 20…60 % of the reflected one in the channel where it is strongest.

Seeds and cameras: :data:`DEV_CAMERAS` with seeds 0…9 999 were used to develop and set the thresholds,
:data:`TEST_CAMERAS` with seeds 10 000…19 999 are used by the tests, :data:`BENCHMARK_CAMERAS` (the retrieval benchmark's
held-out cameras) with seeds ≥ 1 000 000 by ``benchmarks/diagnose.py``.

References
----------
.. [Han2012] Han et al., CVPR 2012: eqs. 1–2, the fluorescent patch.
.. [CIE015] CIE 015:2018: the F, HP and LED illuminant tables of the off-locus lamps (via colour-science).
"""

from __future__ import annotations

import csv
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
from numpy.typing import NDArray

from ..camera import DEFAULT_NOISE, CameraNoise, render
from ..daylight import daylight_locus_xy, daylight_spectrum
from ..observations import Observations
from ..priors import unseen_reflectances
from ..spectra import GRID, WAVELENGTHS, resample_columns
from . import datasets
from .simulate import SimulatedHistory

__all__ = [
    "EFFECTS",
    "LOCATED_EFFECTS",
    "DEV_CAMERAS",
    "TEST_CAMERAS",
    "BENCHMARK_CAMERAS",
    "HiddenEffect",
    "hide_effect",
    "draw_patch_change",
    "soiled",
    "draw_shadow",
    "lamp_spectra",
    "LAMP_FRAMES",
    "SHORT_WAVE_EXCITATION_NM",
]

EFFECTS: tuple[str, ...] = (
    "none",
    "nonlinear_response",
    "black_offset",
    "clipping",
    "patch_change",
    "shadow",
    "off_locus_illuminant",
    "fluorescence",
)
"""Effect names (the contract of ``illumon diagnose``)."""

LOCATED_EFFECTS = {"patch_change": ("patch", "frame"), "shadow": ("patch", "frame"), "fluorescence": ("patch",)}
"""Effects reported with a patch and/or an onset frame."""

DEV_CAMERAS = ("Canon_20D", "Canon_40D", "Nikon_D200", "Nikon_D80", "Canon_5DMarkII", "Nikon_D700")
TEST_CAMERAS = ("Canon_300D", "Nikon_D3X", "Canon_50D", "Nikon_D40", "Hasselblad_H2", "Nikon_D7000_ssf")
BENCHMARK_CAMERAS = ("Canon_600D", "Nikon_D5100", "Pentax_K-5", "Point_Grey_Grasshopper2_14S5C", "Nikon_Z6_ssf", "Phase_One")

SHORT_WAVE_EXCITATION_NM = 600.0
"""Fluorophores whose visible excitation peaks at or above this wavelength are not drawn. The fluorescence effect is
emission proportional to the *short-wave* light a patch absorbs; the compilation's far-red-excited laboratory dyes
(Cy5, APC, ATTO 647, DY-6xx, chlorophyll; 19 % of its visible entries) absorb and emit within the red channel, where
their emission follows the light exactly as reflected red light does. Even with the true illuminants, camera and
reflectance (plus an 8-function correction), such a patch is fitted by a reflectance within noise (development seeds
101, 107…109: excess χ² −14…+29 over ~90 values), so the history is, by the definition of ``none`` (nothing the model cannot fit),
clean."""

_LAMPS = (
    "FL2", "FL4", "FL5", "FL11", "FL12", "FL3.1", "FL3.3", "FL3.5", "HP1", "HP2", "HP3",
    "LED-B1", "LED-B3", "LED-BH1", "LED-RGB1", "LED-V1",
)
"""Lamps far from daylight: CCT ≤ 4250 K (below the daylight locus) or Duv ≥ 0.009 (greenish); daylight simulators
such as FL7 or FL3.15 are left out, a camera cannot tell them from daylight."""


@dataclass
class HiddenEffect:
    """A simulated history with one hidden effect and the truth about it.

    Attributes
    ----------
    effect
        One of :data:`EFFECTS`.
    patch, frame
        Index of the affected patch and of the onset frame (patch change, first shaded frame), or ``None``.
    parameters
        The effect's parameters (gamma, offsets, shaded frames, lamp, fluorophore, strength, …).
    history
        Observations and ground truth (illuminants actually lighting each frame, reflectances before any change).
    """

    effect: str
    patch: int | None
    frame: int | None
    parameters: dict = field(default_factory=dict)
    history: SimulatedHistory | None = None

    @property
    def observations(self) -> Observations:
        """The simulated observations."""
        assert self.history is not None
        return self.history.observations


LAMP_FRAMES = {
    "minority": lambda f: (3, max(4, f // 5), 0.6, 1.0),
    "majority": lambda f: (round(2 * f / 3), round(2 * f / 3), 0.35, 0.8),
}
"""How many frames an ``off_locus_illuminant`` lamp lights and its share of their light: ``lamp_frames`` → ``F`` →
(fewest, most frames, lowest, highest share). ``minority`` hid the outside check's case of a scene lit by lamps most
of the time (the spectral stage judged lamp-lit frames as outliers of the history's typical frame, itself lamp-lit)."""


@lru_cache(maxsize=1)
def lamp_spectra() -> dict[str, NDArray[np.float64]]:
    """CIE fluorescent, high-pressure and LED illuminants from colour-science on the grid (each 100 at 560 nm)."""
    import colour

    out = {}
    for name in _LAMPS:
        sd = colour.SDS_ILLUMINANTS[name]
        v = resample_columns(sd.wavelengths, sd.values[:, None], GRID)[:, 0]
        out[name] = 100.0 * v / v[32]
    return out


@lru_cache(maxsize=1)
def _compilation_fluorophores() -> list[tuple[str, NDArray[np.float64], NDArray[np.float64]]]:
    """Fluorophores of the McNamara & Boswell compilation with visible excitation: (name, excitation, emission)."""
    d = datasets.shared_data_dir()
    if d is None:
        raise FileNotFoundError("measured data not found: set ILLUMON_SHARED_DATA or place shared/data beside the project")
    with open(d / "fluorophores" / "mcnamara_boswell.csv", newline="") as fh:
        rows = list(csv.reader(fh))
    wl = np.asarray([float(x) for x in rows[0][3:]])
    spectra: dict[tuple[str, str], dict[str, NDArray[np.float64]]] = {}
    for row in rows[1:]:
        vals = np.asarray([float(x) if x else 0.0 for x in row[3:]])
        spectra.setdefault((row[0], row[1]), {})[row[2]] = vals
    out = []
    for (name, _), d2 in spectra.items():
        if "excitation" not in d2 or "emission" not in d2:
            continue
        ex = np.clip(resample_columns(wl, d2["excitation"][:, None], GRID)[:, 0], 0, None)
        em = np.clip(resample_columns(wl, d2["emission"][:, None], GRID)[:, 0], 0, None)
        if ex.max() < 0.3 or em.max() <= 0 or not 440 <= WAVELENGTHS[int(np.argmax(em))] <= 680:
            continue
        # the visible emission must lie mostly at longer wavelengths than the visible excitation (Stokes shift)
        if np.argmax(em) <= np.argmax(ex):
            continue
        # the effect is emission driven by short-wave light: excitation peaks in the blue…orange (< 600 nm, as
        # in daylight-fluorescent pigments, inks and optical brighteners); see SHORT_WAVE_EXCITATION_NM
        if WAVELENGTHS[int(np.argmax(ex))] >= SHORT_WAVE_EXCITATION_NM:
            continue
        out.append((name, ex / ex.max(), em / em.max()))
    return out


def _daylight_run(rng: np.random.Generator, frames: int) -> NDArray[np.float64]:
    """A run of consecutive Granada spectra (acquisition order), every ``stride``-th, ``frames`` long."""
    _, daylight = datasets.load_granada_daylight()
    stride = int(rng.integers(1, 4))
    start = int(rng.integers(0, daylight.shape[0] - stride * frames))
    return daylight[start : start + stride * frames : stride].copy()


def draw_patch_change(rng: np.random.Generator, frames: int, patches: int) -> tuple[int, int]:
    """The changed patch and its onset frame (within the middle 60 % of the history), as every simulator draws them."""
    patch = int(rng.integers(patches))
    frame = int(rng.integers(max(2, round(0.2 * frames)), round(0.8 * frames) + 1))
    return patch, frame


def soiled(reflectance: NDArray[np.float64], darkening: float) -> NDArray[np.float64]:
    """A soiled surface: darkened by ``darkening`` and yellowed (a ramp from 0.6 at 400 nm to 1 at 700 nm)."""
    return reflectance * darkening * (0.6 + 0.4 * (WAVELENGTHS - 400.0) / 300.0)


def draw_shadow(rng: np.random.Generator, frames: int, patches: int) -> tuple[int, int, int, float, float]:
    """The shaded patch, first frame and length of the run (``max(3, F/6)``…``F/2`` frames, inside the history), the
    skylight's correlated colour temperature (10 000…25 000 K) and the shade's level (0.15…0.45 of the daylight)."""
    patch = int(rng.integers(patches))
    length = int(rng.integers(max(3, frames // 6), frames // 2 + 1))
    frame = int(rng.integers(1, frames - length - 1))
    return patch, frame, length, float(rng.uniform(10000, 25000)), float(rng.uniform(0.15, 0.45))


def hide_effect(
    effect: str,
    camera: str,
    seed: int,
    *,
    frames: int | None = None,
    patches: int | None = None,
    noise: CameraNoise = DEFAULT_NOISE,
    lamp_frames: str = "minority",
) -> HiddenEffect:
    """Simulate a fixed-camera history with one hidden ``effect`` (seeded; see the module docstring for the models).

    Parameters
    ----------
    effect
        One of :data:`EFFECTS`.
    camera
        Name of a measured camera (:func:`illumon.simulation.datasets.camera_names`).
    seed
        Seed of every random choice (frames, patches, effect parameters, noise).
    frames, patches
        History size; random in 24…40 frames and 8…12 patches by default.
    noise
        Shot/read noise, exposure jitter and metering target.
    lamp_frames
        For ``off_locus_illuminant``, which frames the lamp lights (:data:`LAMP_FRAMES`): ``"minority"`` (3…F/5
        frames, 60…100 % of the light, the default) or ``"majority"`` (two thirds of the frames, 35…80 %: a scene lit
        by lamps most of the time, as the outside check's histories of 36 frames with 24 mixed).

    Returns
    -------
    HiddenEffect
    """
    if effect not in EFFECTS:
        raise ValueError(f"unknown effect {effect!r}; choose from {', '.join(EFFECTS)}")
    rng = np.random.default_rng(seed)
    f = int(frames or rng.integers(24, 41))
    p = int(patches or rng.integers(8, 13))
    c = datasets.load_camera(camera)
    e = _daylight_run(rng, f)
    _, pool = unseen_reflectances()
    chosen = rng.choice(pool.shape[0], p, replace=False)
    r = pool[chosen]
    clean = render(c, e, r)  # F × P × 3
    lit = e.copy()
    if lamp_frames not in LAMP_FRAMES:
        raise ValueError(f"unknown lamp_frames {lamp_frames!r}; choose from {', '.join(LAMP_FRAMES)}")
    patch, frame, params = _scene_effect(effect, rng, c, e, r, pool, chosen, clean, lit, lamp_frames)
    y, k = _camera_effect(effect, rng, clean, noise, params)
    y = np.clip(y, 0.0, 1.0)
    obs = Observations([f"f{i:05d}" for i in range(f)], [f"p{j:02d}" for j in range(p)], y, [""] * f)
    hist = SimulatedHistory(obs, lit, r, k, c)
    return HiddenEffect(effect, patch, frame, params, hist)


def _scene_effect(effect: str, rng: np.random.Generator, c: NDArray[np.float64], e: NDArray[np.float64],
                  r: NDArray[np.float64], pool: NDArray[np.float64], chosen: NDArray[np.int64],
                  clean: NDArray[np.float64], lit: NDArray[np.float64], lamp_frames: str = "minority"
                  ) -> tuple[int | None, int | None, dict]:
    """The effects in the scene and its light (patch change, shadow, off-locus light, fluorescence), drawn from
    ``rng`` and rendered into ``clean`` (F × P × 3) and ``lit`` (the light of each frame) in place; the affected
    patch, onset frame and parameters. Other effects leave both unchanged.

    References
    ----------
    .. [Han2012] Han et al., CVPR 2012: eqs. 1–2, the fluorescent patch.
    """
    f, p = clean.shape[0], clean.shape[1]
    patch: int | None = None
    frame: int | None = None
    params: dict = {}
    if effect == "patch_change":
        patch, frame = draw_patch_change(rng, f, p)
        if rng.random() < 0.5:
            others = np.setdiff1d(np.arange(pool.shape[0]), chosen)
            new = pool[int(rng.choice(others))]
            params["kind"] = "replaced"
        else:
            dark = float(rng.uniform(0.5, 0.8))
            new = soiled(r[patch], dark)
            params.update(kind="soiled", darkening=dark)
        clean[frame:, patch] = render(c, e[frame:], new[None])[:, 0]
    elif effect == "shadow":
        patch, frame, length, sky_cct, level = draw_shadow(rng, f, p)
        sky = daylight_spectrum(daylight_locus_xy(np.array([sky_cct])))[0]
        sky = sky / sky[32]
        run = np.arange(frame, frame + length)
        shade = level * e[run, 32:33] * sky[None]
        clean[run, patch] = render(c, shade, r[patch][None])[:, 0]
        params.update(shaded_frames=[int(i) for i in run], sky_cct=sky_cct, level=level)
    elif effect == "off_locus_illuminant":
        n_lo, n_hi, m_lo, m_hi = LAMP_FRAMES[lamp_frames](f)
        n_off = int(rng.integers(n_lo, n_hi + 1))
        which = np.sort(rng.choice(f, n_off, replace=False))
        lamps = lamp_spectra()
        name = str(rng.choice(list(lamps)))
        mix = rng.uniform(m_lo, m_hi, n_off)
        lamp = lamps[name]
        for i, m in zip(which, mix, strict=True):
            lit[i] = (1 - m) * e[i] + m * lamp * e[i, 32] / lamp[32]
        clean[which] = render(c, lit[which], r)
        params.update(frames=[int(i) for i in which], lamp=name, lamp_fraction=[float(m) for m in mix])
    elif effect == "fluorescence":
        patch = int(rng.integers(p))
        fl = _compilation_fluorophores()
        name, ex, em = fl[int(rng.integers(len(fl)))]
        q = e @ ex  # absorbed light per frame (Han et al. eq. 1, the integral over λ')
        emitted = q[:, None] * em[None]  # eq. 2: a fixed emission spectrum scaled by k_p
        cam_em = emitted @ c  # F × 3
        refl = clean[:, patch]
        ch = int(np.argmax(cam_em.sum(0)))
        ratio = float(rng.uniform(0.2, 0.6))
        s = ratio * np.median(refl[:, ch]) / np.median(cam_em[:, ch])
        clean[:, patch] = refl + s * cam_em
        params.update(fluorophore=name, emission_ratio=ratio, emission_peak_nm=float(WAVELENGTHS[int(np.argmax(em))]))
    return patch, frame, params


def _camera_effect(effect: str, rng: np.random.Generator, clean: NDArray[np.float64], noise: CameraNoise,
                   params: dict) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The camera's part: auto-exposure (a brighter metering target for ``clipping``), shot and read noise, and the
    output effects (tone curve, black offset), drawn from ``rng`` after the scene's; the values before the final
    clip to 0…1 and the exposures. ``params`` gains the effect's parameters."""
    f = clean.shape[0]
    peak = clean.max(axis=(1, 2))
    target = noise.target
    if effect == "clipping":
        target = float(rng.uniform(1.05, 1.4))
        params["metering_target"] = target
    k = target / peak * np.exp(noise.exposure_jitter * rng.standard_normal(f))
    if effect != "clipping":
        k = np.minimum(k, 0.9 / peak)  # highlight guard of the metering: the brightest patch stays below 0.9
    y = clean * k[:, None, None]
    sigma = np.sqrt(noise.shot * np.clip(y, 0, None) + noise.read**2)
    y = np.clip(y + sigma * rng.standard_normal(y.shape), 0.0, None)
    if effect == "nonlinear_response":
        gamma = float(rng.uniform(1.5, 2.6))
        y = np.clip(y, 0.0, 1.0) ** (1.0 / gamma)
        params["gamma"] = gamma
    elif effect == "black_offset":
        b = rng.uniform(0.015, 0.06, 3)
        y = y + b
        params["offsets"] = [float(v) for v in b]
    elif effect == "clipping":
        params["clipped_fraction"] = float(np.mean(y >= 1.0))
    return y, k
