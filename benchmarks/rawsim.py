"""An independent raw-camera simulator for tests and benchmarks (issue 16), written apart from :mod:`illumon.simulation.simulate`.

It shares no noise, exposure or rounding code with the project's own simulator; it reads the measured data through
:mod:`illumon.simulation.datasets` and resamples with :mod:`illumon.spectra` only. The pipeline follows the standard raw model of
an image sensor (EMVA Standard 1288, release 4.0, 2021; Healey & Kondepudy, "Radiometric CCD camera calibration and
noise estimation", IEEE TPAMI 16(3), 1994; Foi et al., "Practical Poissonian-Gaussian noise modeling and fitting for
single-image raw-data", IEEE TIP 17(10), 2008):

1. Spectral radiance of each region ``L_fp(λ) = E_f(λ) R_p(λ)`` (or a given radiance, e.g. with fluorescence),
   per-pixel texture ``(1 + t·u)``, ``u ~ U(−1, 1)`` fixed per pixel (the camera does not move).
2. Auto-exposure in whole third-stops (a real camera's exposure steps), metering a scene percentile of the green
   channel to a target fraction of the full well, with a small metering error; so the exposure jumps between frames.
3. Electrons per pixel: Poisson photon shot noise of the mean electron count, full-well clipping.
4. Digital numbers: electrons divided by the conversion gain (e⁻/DN), Gaussian read noise (in e⁻), the black level
   added, rounded to integers and clipped to the ADC range ``0 … 2^bits − 1``.
5. The camera's raw converter subtracts the black level and clips at 0 (the censoring at 0 of dark channels),
   divides by the white level, applies optional white-balance gains, a 3×3 colour matrix (clipped to 0…1) and a tone
   curve (``"srgb"`` via colour-science's IEC 61966-2-1 encoding, a gamma, or linear), and quantises the encoded value
   to ``bits`` bits again.
6. A region's value is the mean of its ``pixels`` encoded pixels (and its spread the pixels' standard deviation), as
   the service measures a region of a frame.

Rendered output (:func:`rendering`, from the real photographs of ``benchmarks/real.py``): the simulators had assumed
that a processed camera delivers its sensor RGB through fixed white-balance gains and at most a mild matrix (imgsim's
output-profile boost). Real IP, surveillance and phone cameras deliver **sRGB primaries**: a white-preserving matrix
from the sensor to linear sRGB (off-diagonal terms of −0.3…−1, so saturated patches go negative and are clipped at 0
by the pipeline), after a white balance that is either a daylight preset or the camera's own automatic balance that
changes every frame. That assumption hid why illumon's raw-sensor prior did worse than doing nothing on a phone's
output (issue 26); :func:`rendering` gives the matrix and gains to pass to :func:`simulate_raw_history`.

Data splits (module constants) are used by every benchmark that scores on this simulator: development cameras,
reflectances and daylight for choosing methods and margins, score sets for the figures.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass

import numpy as np
from illumon.observations import Observations
from illumon.priors import unseen_reflectances
from illumon.simulation import datasets
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "DEV_CAMERAS",
    "SCORE_CAMERAS",
    "DEV_REFLECTANCE_SETS",
    "SCORE_REFLECTANCE_SETS",
    "DEV_DAYLIGHT",
    "SCORE_DAYLIGHT",
    "manufacturer",
    "reflectance_pool",
    "daylight_pool",
    "daylight_run",
    "lamp_run",
    "pale",
    "camera_profile",
    "RawHistory",
    "simulate_raw_history",
    "rendering",
    "encode_tone",
    "decode_tone",
    "PIPELINE_VARIANTS",
]

# --- data splits ------------------------------------------------------------------------------------------------

DEV_CAMERAS: tuple[str, ...] = (
    "Nikon_D200", "Nikon_D3", "Nikon_D300s", "Nikon_D3500_ssf", "Nikon_D3X", "Nikon_D40", "Nikon_D50",
    "Nikon_D50_ssf", "Nikon_D5100", "Nikon_D700", "Nikon_D7000_ssf", "Nikon_D80", "Nikon_Z6_ssf",
    "Point_Grey_Grasshopper2_14S5C",
)
"""Development cameras: every Nikon (13 files, the D50 measured two ways among them) and the Point Grey machine-vision
camera. Split by manufacturer, so no manufacturer is on both sides. :data:`illumon.simulation.effects.DEV_CAMERAS`
(three Canons and three Nikons) is not reused: it straddles the two largest manufacturers, so a margin chosen on it
has seen the Canon models scored here."""

SCORE_CAMERAS: tuple[str, ...] = (
    "Canon_20D", "Canon_300D", "Canon_40D", "Canon_500D", "Canon_50D", "Canon_5DMarkII", "Canon_600D",
    "Hasselblad_H2", "Pentax_K-5", "Phase_One",
)
"""Score cameras: every Canon, Hasselblad, Pentax and Phase One (no manufacturer of :data:`DEV_CAMERAS`)."""

DEV_REFLECTANCE_SETS: tuple[str, ...] = datasets.REFLECTANCE_SETS
"""Development surfaces: the five measured sets in ``../shared/data/reflectances`` (Munsell, Vrhel, Joensuu, DuPont,
SFU), the ones the shipped reflectance basis and prior were built from (``core/illumon/data/README.md``)."""

SCORE_REFLECTANCE_SETS: tuple[str, ...] = ("colourchecker_babel", "cie1995_tcs")
"""Score surfaces: colour-science's ColorChecker (BabelColor average) and CIE 1995 TCS01–14, never used to build a
prior. The NIST CQS 9.0 VS1–15 of :func:`illumon.priors.unseen_reflectances` are left out: all fifteen are
spectra of the Munsell matt set the shipped basis was built from (identical values, e.g. VS1 = 5R 4/14)."""

DEV_DAYLIGHT = slice(0, 1300)
"""Development daylight: the first 1300 Granada spectra in file order (the training half of the shipped daylight
models, ``core/illumon/data/README.md``)."""

SCORE_DAYLIGHT = slice(1300, 2600)
"""Score daylight: Granada spectra 1300…2599, held out of the shipped measured-daylight model and mixture (the
sensitivity estimator's daylight prior used all 2600; its benchmark says so)."""

def manufacturer(camera: str) -> str:
    """Manufacturer of a measured camera from its file stem (:func:`illumon.sensitivity.evaluate.camera_manufacturer`,
    imported when called so the simulator does not load the sensitivity package)."""
    from illumon.sensitivity.evaluate import camera_manufacturer

    return camera_manufacturer(camera)


def reflectance_pool(split: str) -> list[NDArray[np.float64]]:
    """Surfaces of a split as a list of sets (each n × 61): ``"dev"`` or ``"score"``."""
    if split == "dev":
        return [datasets.load_reflectance_set(s)[1] for s in DEV_REFLECTANCE_SETS]
    if split == "score":
        names, r = unseen_reflectances()
        return [r[[i for i, n in enumerate(names) if n.startswith(pre)]] for pre in ("cc_", "tcs_")]
    raise ValueError(f"split must be 'dev' or 'score', got {split!r}")


def draw_reflectances(split: str, n: int, rng: np.random.Generator) -> NDArray[np.float64]:
    """``n`` distinct surfaces of a split: a set drawn uniformly (so Munsell does not dominate), then a spectrum."""
    pool = reflectance_pool(split)
    sizes = np.array([len(s) for s in pool])
    seen: set[tuple[int, int]] = set()
    out = []
    while len(out) < min(n, int(sizes.sum())):
        k = int(rng.integers(len(pool)))
        j = int(rng.integers(sizes[k]))
        if (k, j) not in seen:
            seen.add((k, j))
            out.append(pool[k][j])
    return np.asarray(out)


def daylight_pool(split: str) -> NDArray[np.float64]:
    """Granada daylight spectra of a split (n × 61, each 100 at 560 nm)."""
    _, day = datasets.load_granada_daylight()
    if split == "dev":
        return day[DEV_DAYLIGHT]
    if split == "score":
        return day[SCORE_DAYLIGHT]
    raise ValueError(f"split must be 'dev' or 'score', got {split!r}")


def daylight_run(split: str, frames: int, rng: np.random.Generator) -> NDArray[np.float64]:
    """A run of ``frames`` consecutive spectra of the split (every 1st…3rd acquisition), with the light level of a
    changing sky: a smooth random walk of ±1 stop over the run (global irradiance changes with sun and cloud)."""
    pool = daylight_pool(split)
    stride = int(rng.integers(1, 4))
    start = int(rng.integers(0, pool.shape[0] - stride * frames))
    run = pool[start : start + stride * frames : stride].copy()
    level = np.exp(np.cumsum(0.15 * rng.standard_normal(frames)))
    return run * np.clip(level, 0.5, 2.0)[:, None]


def lamp_run(frames: int, rng: np.random.Generator) -> NDArray[np.float64]:
    """A history lit only by lamps (the real lamp-lit scenes of ``benchmarks/lamps.py``): each frame one or two lamps
    of the CIE tables (A, the LED and fluorescent series, high-pressure lamps; :func:`illumon.model.general.
    cie_lamp_spectra`) at random shares, at a level that wanders by ±½ stop. The simulators' histories had all been
    daylight, so a camera balanced for daylight was assumed to see a history whose mean white is near grey — the
    assumption that hid the real lamp-lit scenes' 10–16° errors (issue 28)."""
    from illumon.model.general import cie_lamp_spectra

    lamps = cie_lamp_spectra()
    out = np.empty((frames, lamps.shape[1]))
    for f in range(frames):
        i, j = rng.integers(0, len(lamps), 2)
        w = float(rng.uniform(0.0, 1.0))
        out[f] = w * lamps[i] + (1 - w) * lamps[j]
    level = np.exp(np.clip(0.1 * np.cumsum(rng.standard_normal(frames)), -0.35, 0.35))
    return out * level[:, None]


FLARE_RMS = 0.12
"""Root mean square of the veiling glare :func:`flare_draw` draws, as a fraction of the frame's mean region signal:
what the grey patches of the real development photographs show (``python benchmarks/flare.py``)."""


def flare_draw(frames: int, rng: np.random.Generator, rms: float = FLARE_RMS) -> NDArray[np.float64]:
    """Veiling glare of each frame (``flare`` of :func:`simulate_raw_history`): half-normal, root mean square ``rms``
    (glare only adds light)."""
    return np.abs(rng.normal(0.0, rms, frames))


def pale(reflectances: ArrayLike, chroma: float = 0.15) -> NDArray[np.float64]:
    """Surfaces of a man-made interior or street (walls, floors, asphalt, tables): the measured ``reflectances`` with
    their spectral variation around their own mean scaled by ``chroma`` — their colours kept, their saturation cut
    (the real table-top scenes' regions spread 0.004–0.09 in log chromaticity, the measured sets' 0.53)."""
    r = np.asarray(reflectances, dtype=float)
    m = r.mean(axis=1, keepdims=True)
    return np.clip(m + chroma * (r - m), 0.0, 1.0)


def grey_average(reflectances: ArrayLike, chroma: float = 0.5) -> NDArray[np.float64]:
    """Surfaces of a colourful man-made room that averages grey: the measured ``reflectances`` made half as saturated
    (:func:`pale` at ``chroma``), then each divided by the scene's mean spectrum (times its mean level), so the
    scene's average reflectance is flat while its surfaces keep their colours. What the real chart-free photographs
    showed (``benchmarks/real_pairs.py``: regions spreading 0.03–0.25 in log chromaticity, averaging within 0.05 of
    grey) and the measured sets never draw: a scene of measured surfaces averages like their mean surface (warm,
    0.2 / −0.2 in log r/g, b/g through the mean camera), the reflectance prior's own mean."""
    r = pale(reflectances, chroma)
    mean = r.mean(axis=0, keepdims=True)
    return np.clip(r * mean.mean() / np.clip(mean, 1e-3, None), 0.0, 1.0)


def camera_profile(camera: str, *, iso: float | None = None, rng: np.random.Generator | None = None) -> dict:
    """Sensor constants of a simulated body for ``camera`` (stable per name): full well, read noise, black level and
    ADC depth typical of its class, and the conversion gain at an ISO setting (base ISO 100 maps the full well to the
    ADC's white; ISO ``s`` divides the gain by ``s/100``). ``iso`` None draws one of 100…1600 from ``rng``."""
    h = np.random.default_rng(zlib.crc32(camera.encode()))
    full_well = float(h.uniform(15_000, 60_000))
    read = float(h.uniform(2.0, 8.0))
    adc_bits = int(h.choice([12, 14]))
    black = float({12: 256, 14: 1024}[adc_bits] if h.random() < 0.7 else {12: 128, 14: 512}[adc_bits])
    if iso is None:
        iso = float((rng or np.random.default_rng()).choice([100, 200, 400, 800, 1600]))
    gain = full_well / (2**adc_bits - 1 - black) / (iso / 100.0)
    return {"full_well_e": full_well, "read_noise_e": read, "black_level": black, "adc_bits": adc_bits,
            "conversion_gain": gain, "iso": iso}


# --- tone curves ------------------------------------------------------------------------------------------------


def encode_tone(linear: ArrayLike, tone: str | float | None) -> NDArray[np.float64]:
    """Encode linear values 0…1 with a tone curve: ``"srgb"`` (IEC 61966-2-1, via colour-science), a float gamma
    γ (``v = x^(1/γ)``), or ``None`` (linear)."""
    x = np.clip(np.asarray(linear, dtype=float), 0.0, 1.0)
    if tone is None:
        return x
    if isinstance(tone, str):
        import colour

        if tone.lower() == "bt709":
            return np.asarray(colour.models.oetf_BT709(x), dtype=float)
        if tone.lower() != "srgb":
            raise ValueError(f"tone must be 'srgb', 'bt709', a gamma or None, got {tone!r}")
        return np.asarray(colour.models.eotf_inverse_sRGB(x), dtype=float)
    return x ** (1.0 / float(tone))


def decode_tone(encoded: ArrayLike, tone: str | float | None) -> NDArray[np.float64]:
    """Inverse of :func:`encode_tone` (NaN stays NaN)."""
    v = np.asarray(encoded, dtype=float)
    if tone is None:
        return v.copy()
    if isinstance(tone, str):
        import colour

        if tone.lower() == "bt709":
            return np.asarray(colour.models.oetf_inverse_BT709(np.clip(v, 0.0, 1.0)), dtype=float)
        return np.asarray(colour.models.eotf_sRGB(np.clip(v, 0.0, 1.0)), dtype=float)
    return np.clip(v, 0.0, None) ** float(tone)


# --- the simulator ----------------------------------------------------------------------------------------------


@dataclass
class RawHistory:
    """A simulated history with its ground truth (see :func:`simulate_raw_history`).

    Attributes
    ----------
    observations
        Region means as the camera delivers them (encoded, 0…1), NaN where missing.
    linear_output
        The region means decoded with the declared tone curve (F × P × 3): what a user feeds a linear analysis.
    true_white, true_white_raw
        Response of a perfect white diffuser (F × 3) in the output linear space (after the matrix, before applied
        gains) and in the camera's raw space, on the same 0…1 scale and exposure as the frame (may exceed 1).
    illuminants, reflectances
        Spectra that lit each frame (F × 61) and the surfaces (P × 61).
    exposure
        Exposure factor per frame (electrons per unit of ``Σλ C E R``).
    pixel_sd
        Standard deviation of the encoded pixels of each region (F × P × 3).
    settings
        The sensor and pipeline constants used.
    """

    observations: Observations
    linear_output: NDArray[np.float64]
    true_white: NDArray[np.float64]
    true_white_raw: NDArray[np.float64]
    illuminants: NDArray[np.float64]
    reflectances: NDArray[np.float64]
    exposure: NDArray[np.float64]
    pixel_sd: NDArray[np.float64]
    settings: dict


def _auto_exposure(signal: NDArray[np.float64], saturation_e: float, target: float, percentile: float,
                   rng: np.random.Generator, error: float) -> NDArray[np.float64]:
    """Exposure (e⁻ per unit signal) per frame in whole third-stops: the ``percentile`` of the green regions to
    ``target`` of the saturation charge (full well, or the ADC's white at the gain if lower, i.e. at high ISO), with a
    log-normal metering error of ``error`` stops."""
    metered = np.percentile(signal[:, :, 1], percentile, axis=1)
    ideal = target * saturation_e / np.maximum(metered, 1e-300)
    stops = np.log2(ideal) + error * rng.standard_normal(ideal.shape)
    return 2.0 ** (np.round(3.0 * stops) / 3.0)


def simulate_raw_history(
    css: ArrayLike,
    illuminants: ArrayLike,
    reflectances: ArrayLike,
    *,
    rng: np.random.Generator | int | None = None,
    bits: int = 12,
    conversion_gain: float | None = None,
    read_noise_e: float = 3.0,
    black_level: float | ArrayLike | None = None,
    full_well_e: float = 20_000.0,
    adc_bits: int | None = None,
    black_subtracted: ArrayLike | None = None,
    auto_exposure: bool = True,
    ae_target: float = 0.45,
    ae_percentile: float = 98.0,
    ae_error_stops: float = 0.1,
    exposure: ArrayLike | None = None,
    matrix: ArrayLike | None = None,
    tone: str | float | None = None,
    applied_gains: ArrayLike | None = None,
    pixels: int = 400,
    texture: float = 0.0,
    radiance: ArrayLike | None = None,
    missing_fraction: float = 0.0,
    jpeg_dc_step: float | None = None,
    mean_bits: int | None = None,
    flare: ArrayLike | None = None,
) -> RawHistory:
    """Simulate a fixed camera's history of static regions through a raw pipeline (module docstring).

    Parameters
    ----------
    css
        Camera sensitivities (61 × 3) on :data:`illumon.spectra.GRID`.
    illuminants
        Spectrum lighting each frame (F × 61).
    reflectances
        Region reflectances (P × 61).
    rng
        Random generator or seed.
    bits
        Bit depth of the delivered (encoded) values: 8, 10 or 12 (or more).
    conversion_gain
        e⁻ per DN of the ADC; default maps the full well to the ADC's white (base ISO).
    read_noise_e
        Read noise (e⁻ rms per pixel).
    black_level
        ADC black level in DN, scalar or per channel (default 256 for ≥ 12-bit ADCs, 16 otherwise).
    full_well_e
        Full-well capacity (e⁻); pixels saturate there.
    adc_bits
        ADC depth (default ``max(bits, 12)``).
    black_subtracted
        Black level the raw converter subtracts (default ``black_level``; a lower value leaves a pedestal).
    auto_exposure
        Meter every frame (third-stop steps); otherwise the first frame's exposure is kept, or ``exposure`` is used.
    ae_target, ae_percentile, ae_error_stops
        Fraction of the saturation charge (full well, or the ADC white at high gain) for the metered percentile of
        green regions, the percentile, and the metering error (stops, log-normal).
    exposure
        Exposure per frame (e⁻ per unit ``Σλ C E R``), overriding the metering.
    matrix
        3×3 colour matrix applied to the linear raw values (output = M · raw), or None.
    tone
        ``"srgb"``, a gamma (float) or None (linear).
    applied_gains
        White-balance gains per frame (F × 3 or 3,) applied to raw values before the matrix, or None.
    pixels
        Pixels averaged in each region.
    texture
        Pixel-to-pixel reflectance texture ±``texture`` (uniform), fixed over frames.
    radiance
        Optional spectral radiance per frame and region (F × P × 61), replacing ``illuminants · reflectances``
        (effects: changed, shaded or fluorescent regions).
    missing_fraction
        Probability that a region is missing (occluded) in a frame; every frame keeps at least two regions.
    jpeg_dc_step
        JPEG-like rounding of the output (None: none): the encoded pixels of a region in blocks of 64 (8×8), each
        block's mean rounded to a multiple of this many codes (the quantised DC coefficient, ITU-T T.81: a
        quantisation-table entry ``Q`` rounds the block mean to ``Q/8`` codes), then every pixel to a code again.
    mean_bits
        Deliver each region's mean rounded to a code of this many bits (None: the mean of the coded pixels, as the
        service measures it): software that averages the pixels at full precision and reports integer codes.
    flare
        Veiling glare per frame (scalar or F,): light scattered in the lens adds this fraction of the frame's mean
        region signal (per channel) to every region before the sensor (None or 0: none). The real photographs showed
        3–19 % of the mean, changing from frame to frame (:func:`flare_draw`); before this parameter every simulated
        region was its own light × reflectance alone.

    Returns
    -------
    RawHistory
    """
    rng = np.random.default_rng(rng)
    c = np.asarray(css, dtype=float)
    e = np.atleast_2d(np.asarray(illuminants, dtype=float))
    r = np.atleast_2d(np.asarray(reflectances, dtype=float))
    f, p = e.shape[0], r.shape[0]
    adc = int(adc_bits or max(bits, 12))
    adc_max = 2**adc - 1
    black = np.broadcast_to(np.asarray(256.0 if adc >= 12 else 16.0) if black_level is None
                            else np.asarray(black_level, dtype=float), (3,)).astype(float)
    sub = black if black_subtracted is None else np.broadcast_to(np.asarray(black_subtracted, float), (3,))
    white_dn = adc_max - black  # a saturated raw value after black subtraction
    gain = float(conversion_gain) if conversion_gain is not None else float(full_well_e / white_dn.min())
    if radiance is None:
        signal = np.einsum("fl,pl,lc->fpc", e, r, c)
    else:
        signal = np.einsum("fpl,lc->fpc", np.asarray(radiance, dtype=float), c)
    if flare is not None:
        glare = np.broadcast_to(np.asarray(flare, dtype=float), (f,))
        signal = signal + glare[:, None, None] * signal.mean(axis=1, keepdims=True)
    if exposure is not None:
        k = np.broadcast_to(np.asarray(exposure, dtype=float), (f,)).copy()
    else:
        k = _auto_exposure(signal, min(full_well_e, gain * float(white_dn.min())), ae_target, ae_percentile, rng, ae_error_stops)
        if not auto_exposure:
            k = np.full(f, k[0])
    # per pixel: texture fixed over frames, Poisson electrons, full well, read noise, ADC
    tex = 1.0 + texture * rng.uniform(-1.0, 1.0, (1, p, 1, pixels)) if texture > 0 else 1.0
    mean_e = np.broadcast_to((k[:, None, None] * signal)[..., None] * tex, (f, p, 3, pixels))  # F × P × 3 × N
    electrons = np.minimum(rng.poisson(np.clip(mean_e, 0, None)).astype(float), full_well_e)
    dn = electrons / gain + (read_noise_e / gain) * rng.standard_normal(electrons.shape) + black[:, None]
    raw = np.clip(np.round(dn), 0, adc_max)
    # raw converter: black subtraction with clipping at 0, white level, gains, matrix, tone, output quantisation
    lin = np.clip(raw - sub[:, None], 0.0, None) / white_dn[:, None]
    if applied_gains is not None:
        g = np.broadcast_to(np.asarray(applied_gains, dtype=float), (f, 3))
        lin = lin * g[:, None, :, None]
    if matrix is not None:
        m = np.asarray(matrix, dtype=float)
        lin = np.einsum("ij,fpjn->fpin", m, lin)
    lin = np.clip(lin, 0.0, 1.0)
    levels = 2**bits - 1
    enc = np.round(encode_tone(lin, tone) * levels) / levels
    if jpeg_dc_step is not None:
        enc = _jpeg_like(enc, float(jpeg_dc_step) / levels, levels)
    values = enc.mean(axis=-1)
    if mean_bits is not None:
        values = np.round(values * (2**mean_bits - 1)) / (2**mean_bits - 1)
    sd = enc.std(axis=-1, ddof=1) if pixels > 1 else np.zeros_like(values)
    if missing_fraction > 0:
        drop = rng.random((f, p)) < missing_fraction
        for i in range(f):
            if (~drop[i]).sum() < 2:
                drop[i, rng.choice(p, 2, replace=False)] = False
        values[drop] = np.nan
        sd[drop] = np.nan
    white_raw = (k[:, None] * (e @ c)) / (gain * white_dn[None, :])
    white_out = white_raw @ np.asarray(matrix, dtype=float).T if matrix is not None else white_raw.copy()
    obs = Observations([f"f{i:05d}" for i in range(f)], [f"p{j:02d}" for j in range(p)], values, [""] * f)
    settings = {"bits": bits, "adc_bits": adc, "conversion_gain": gain, "read_noise_e": read_noise_e,
                "black_level": black.tolist(), "black_subtracted": np.asarray(sub).tolist(), "full_well_e": full_well_e,
                "tone": tone, "pixels": pixels, "texture": texture, "mean_bits": mean_bits}
    return RawHistory(obs, decode_tone(values, tone), white_out, white_raw, e, r, k, sd, settings)


def _jpeg_like(enc: NDArray[np.float64], step: float, levels: int) -> NDArray[np.float64]:
    """Encoded pixels (… × N) with every block of 64 pixels' mean rounded to ``step`` (the last, partial block
    too), then every pixel rounded to a code and clipped to 0…1 (see ``jpeg_dc_step``)."""
    n = enc.shape[-1]
    blocks = np.arange(n) // 64
    out = enc.copy()
    for b in range(int(blocks.max()) + 1):
        sel = blocks == b
        m = enc[..., sel].mean(axis=-1, keepdims=True)
        out[..., sel] += np.round(m / step) * step - m
    return np.clip(np.round(out * levels) / levels, 0.0, 1.0)


# --- hidden effects rendered through the raw pipeline -----------------------------------------------------------


@dataclass
class RawHiddenEffect:
    """A raw-pipeline history with one hidden effect (see :func:`hide_effect_raw`); ``observations`` is what the
    camera delivers, ``true_white`` the camera white under each frame's light (raw space, no matrix)."""

    effect: str
    patch: int | None
    frame: int | None
    parameters: dict
    history: RawHistory
    sensitivities: NDArray[np.float64]

    @property
    def observations(self) -> Observations:
        return self.history.observations

    @property
    def true_white(self) -> NDArray[np.float64]:
        return self.history.true_white_raw


PIPELINE_VARIANTS: dict[str, str] = {
    "8bit": "every history delivered as 8-bit codes",
    "16bit": "every history delivered as 16-bit codes",
    "iso6400": "high gain: ISO 3200 or 6400 (32…64× fewer electrons per code than at base ISO)",
    "bt709": "tone curves are the ITU-R BT.709 OETF (a 0.45 power with a linear toe) instead of γ / sRGB",
    "jpeg": "8-bit output with JPEG-like rounding: 8×8 block means rounded to 1…2 codes (DC quantisation 8…16)",
    "small": "small regions: 16…64 pixels each, no texture",
    "rounded": "region means delivered as codes: pixels averaged at 16 bits, each mean rounded to an 8-bit (3 in 4) or "
               "10-bit code (a history written by software that reports integer codes)",
    "lamp_pairs": "lamp-lit frames lit by two lamps at different places (the real MIMO scenes, issue 28): each region "
                  "its own fixed mix of the two, not one light per frame (other effects unchanged)",
}
"""Pipeline variants :func:`hide_effect_raw` can render (``variant=``), for robustness checks the benchmarks do not
score; ``None`` is the standard pipeline (identical histories to before the variants existed)."""


def hide_effect_raw(effect: str, camera: str, seed: int, *, split: str = "score", frames: int | None = None,
                    patches: int | None = None, variant: str | None = None) -> RawHiddenEffect:
    """A history with one hidden effect (the names and parameter ranges of :mod:`illumon.simulation.effects`),
    rendered through the raw pipeline of :func:`simulate_raw_history` with a random body of ``camera``
    (:func:`camera_profile`, ISO 100…1600), output bits 8/10/12, 100…900 pixels per region, 0…5 % texture, and the
    ``split``'s surfaces and daylight.

    The effects are made the way a camera makes them: the tone curve is the camera's output encoding (a gamma in
    1.5…2.6 or sRGB), the black offset is a black level the converter under-subtracts (1.5…6 % of white), clipping is
    metering the brightest region 1.05…1.4 × beyond the full well, and changed, shaded and fluorescent regions and
    lamp light enter as spectral radiance before the sensor.

    ``variant`` (a key of :data:`PIPELINE_VARIANTS`, or None) changes the pipeline after the standard draws: bit
    depth, ISO, tone curve, JPEG-like rounding, region size or region means rounded to codes.
    """
    from illumon.simulation.effects import (
        EFFECTS,
        _compilation_fluorophores,
        draw_patch_change,
        draw_shadow,
        lamp_spectra,
        soiled,
    )
    from illumon.spectra import WAVELENGTHS

    if effect not in EFFECTS:
        raise ValueError(f"unknown effect {effect!r}")
    rng = np.random.default_rng(seed)
    f = int(frames or rng.integers(24, 41))
    p = int(patches or rng.integers(8, 13))
    css = datasets.load_camera(camera)
    prof = camera_profile(camera, rng=rng)
    bits = int(rng.choice([8, 10, 12]))
    e = daylight_run(split, f, rng)
    r = draw_reflectances(split, p, rng)
    lit = e.copy()
    rad = e[:, None, :] * r[None, :, :]
    patch: int | None = None
    frame: int | None = None
    params: dict = {"iso": prof["iso"], "bits": bits}
    kw: dict = {}
    i560 = int(np.argmin(np.abs(WAVELENGTHS - 560)))
    if effect == "nonlinear_response":
        kw["tone"] = "srgb" if rng.random() < 0.5 else float(rng.uniform(1.5, 2.6))
        params["tone"] = kw["tone"]
    elif effect == "black_offset":
        b = rng.uniform(0.015, 0.06, 3)
        white_dn = 2 ** prof["adc_bits"] - 1 - prof["black_level"]
        kw["black_subtracted"] = prof["black_level"] - b * white_dn
        params["offsets"] = [float(v) for v in b]
    elif effect == "clipping":
        kw.update(ae_target=float(rng.uniform(1.05, 1.4)), ae_percentile=100.0)
        params["metering_target"] = kw["ae_target"]
    elif effect == "patch_change":
        patch, frame = draw_patch_change(rng, f, p)
        if rng.random() < 0.5:
            new = draw_reflectances(split, p + 1, rng)[-1]
            params["kind"] = "replaced"
        else:
            dark = float(rng.uniform(0.5, 0.8))
            new = soiled(r[patch], dark)
            params.update(kind="soiled", darkening=dark)
        rad[frame:, patch] = e[frame:] * new[None]
    elif effect == "shadow":
        from illumon.daylight import daylight_locus_xy, daylight_spectrum

        patch, frame, length, sky_cct, level = draw_shadow(rng, f, p)
        sky = daylight_spectrum(daylight_locus_xy(np.array([sky_cct])))[0]
        run = np.arange(frame, frame + length)
        rad[run, patch] = level * e[run, i560 : i560 + 1] * (sky / sky[i560])[None] * r[patch][None]
        params.update(shaded_frames=[int(i) for i in run], level=level)
    elif effect == "off_locus_illuminant":
        n_off = int(rng.integers(3, max(4, f // 5) + 1))
        which = np.sort(rng.choice(f, n_off, replace=False))
        lamps = lamp_spectra()
        name = str(rng.choice(list(lamps)))
        lamp = lamps[name]
        mixes = []
        for i in which:
            m = float(rng.uniform(0.6, 1.0))
            mixes.append(m)
            lit[i] = (1 - m) * e[i] + m * lamp * e[i, i560] / lamp[i560]
        rad = lit[:, None, :] * r[None, :, :]
        params.update(frames=[int(i) for i in which], lamp=name)
    elif effect == "fluorescence":
        patch = int(rng.integers(p))
        fl = _compilation_fluorophores()
        name, ex, em = fl[int(rng.integers(len(fl)))]
        emitted = (e @ ex)[:, None] * em[None]  # Han et al. 2012, eqs. 1–2
        refl = rad[:, patch] @ css
        cam_em = emitted @ css
        ch = int(np.argmax(cam_em.sum(0)))
        ratio = float(rng.uniform(0.2, 0.6))
        rad[:, patch] += ratio * np.median(refl[:, ch]) / np.median(cam_em[:, ch]) * emitted
        params.update(fluorophore=name, emission_ratio=ratio)
    h = simulate_raw_history(
        css, lit, r, rng=rng, bits=bits, conversion_gain=prof["conversion_gain"], read_noise_e=prof["read_noise_e"],
        black_level=prof["black_level"], full_well_e=prof["full_well_e"], adc_bits=prof["adc_bits"],
        pixels=int(rng.integers(100, 901)), texture=float(rng.uniform(0.0, 0.05)), radiance=rad, **kw)
    if variant is None:
        return RawHiddenEffect(effect, patch, frame, params, h, css)
    if variant not in PIPELINE_VARIANTS:
        raise ValueError(f"unknown variant {variant!r}; choose from {', '.join(PIPELINE_VARIANTS)}")
    # re-render the same scene and effect with the variant's pipeline (a generator of its own, seeded from seed)
    vr = np.random.default_rng([seed, zlib.crc32(variant.encode())])
    sim = {"bits": bits, "conversion_gain": prof["conversion_gain"], "pixels": int(vr.integers(100, 901)),
           "texture": float(vr.uniform(0.0, 0.05))}
    if variant == "8bit":
        sim["bits"] = 8
    elif variant == "16bit":
        sim["bits"] = 16
    elif variant == "iso6400":
        sim["conversion_gain"] = camera_profile(camera, iso=float(vr.choice([3200, 6400])))["conversion_gain"]
    elif variant == "bt709" and effect == "nonlinear_response":
        kw["tone"] = "bt709"
    elif variant == "jpeg":
        sim["bits"] = 8
        kw["jpeg_dc_step"] = float(vr.choice([1.0, 2.0]))
    elif variant == "small":
        sim.update(pixels=int(vr.integers(16, 65)), texture=0.0)
    elif variant == "rounded":
        sim["bits"] = 16
        kw["mean_bits"] = int(vr.choice([8, 8, 8, 10]))
    elif variant == "lamp_pairs" and effect == "off_locus_illuminant":
        # what the real lamp-lit scenes show (benchmarks/lamps.py, MIMO): two lamps at different places, so each
        # region sees its own mix of them (its geometry: fixed over the frames) — the assumption broken is one light
        # per frame on every region. The frame's truth is the regions' mean light, as benchmarks/lamps.py scores.
        lamps = lamp_spectra()
        name2 = str(vr.choice([k for k in lamps if k != params["lamp"]]))
        l1, l2 = lamps[params["lamp"]], lamps[name2]
        alpha = vr.uniform(0.0, 1.0, p)  # share of the first lamp at each region
        for i, m in zip(params["frames"], mixes, strict=True):
            pair = alpha[:, None] * l1[None] / l1[i560] + (1 - alpha)[:, None] * l2[None] / l2[i560]
            light = (1 - m) * e[i][None] + m * pair * e[i, i560]  # P × 61
            rad[i] = light * r
            lit[i] = light.mean(axis=0)
        params.update(second_lamp=name2, region_share_first=[round(float(a), 3) for a in alpha])
    params.update(variant=variant, bits=sim["bits"], tone=kw.get("tone", params.get("tone")))
    h = simulate_raw_history(
        css, lit, r, rng=vr, read_noise_e=prof["read_noise_e"], black_level=prof["black_level"],
        full_well_e=prof["full_well_e"], adc_bits=prof["adc_bits"], radiance=rad, **sim, **kw)
    return RawHiddenEffect(effect, patch, frame, params, h, css)


def rendering(css: ArrayLike, illuminants: ArrayLike, scene: ArrayLike, white_balance: str = "preset",
              ) -> tuple[NDArray[np.float64], NDArray[np.float64] | None]:
    """A rendered camera's pipeline (module docstring): the colour matrix to linear sRGB primaries and the white-balance
    gains, for :func:`simulate_raw_history` (``matrix``, ``applied_gains``).

    Parameters
    ----------
    css
        Camera sensitivities (61 × 3).
    illuminants
        Spectrum lighting each frame (F × 61).
    scene
        Reflectances of the scene the camera's automatic balance sees (P × 61).
    white_balance
        ``"preset"``: the matrix's own daylight balance (a fixed preset, no per-frame gains); ``"auto"``: per frame,
        gray-world gains on the raw scene mean (green 1), so every frame's scene mean looks as under the run's mean
        light — a phone's or an IP camera's automatic white balance.

    Returns
    -------
    tuple
        The 3 × 3 matrix (output = M · raw) and the per-frame gains (F × 3), or None for the preset.
    """
    from illumon.camera.primaries import srgb_matrix_for

    css, e, scene = (np.asarray(a, dtype=float) for a in (css, illuminants, scene))
    matrix = srgb_matrix_for(css).T
    if white_balance == "preset":
        return matrix, None
    if white_balance != "auto":
        raise ValueError(f"white_balance must be 'preset' or 'auto', got {white_balance!r}")
    raw_gw = np.einsum("fl,pl,lc->fc", e, scene, css)
    mean_gw = np.einsum("l,pl,lc->c", e.mean(axis=0), scene, css)
    gains = mean_gw / raw_gw
    return matrix, gains / gains[:, 1:2]


def render_chart(css: ArrayLike, illuminant: ArrayLike, reflectances: ArrayLike, noise: float | None = None,
                 rng: np.random.Generator | int | None = None) -> NDArray[np.float64]:
    """A chart photographed through the raw pipeline, as a user would feed it to ``illumon sensitivity``: one frame,
    the brightest green region metered to 70 % of white (third-stop steps, metering error), a body of the camera
    with an ISO of 100…1600 (:func:`camera_profile`, keyed by the curves), output 8/10/12 bits, 400 pixels per
    region, 2 % texture; linear region means scaled so the brightest is 1 (P × 3). ``noise`` is ignored: the noise
    is the pipeline's (the signature of :func:`illumon.sensitivity.evaluate.simulate_chart`)."""
    rng = np.random.default_rng(rng)
    c = np.asarray(css, dtype=float)
    prof = camera_profile(f"css-{zlib.crc32(np.ascontiguousarray(c).tobytes())}", rng=rng)
    h = simulate_raw_history(c, np.atleast_2d(illuminant), reflectances, rng=rng, bits=int(rng.choice([8, 10, 12])),
                             conversion_gain=prof["conversion_gain"], read_noise_e=prof["read_noise_e"],
                             black_level=prof["black_level"], full_well_e=prof["full_well_e"],
                             adc_bits=prof["adc_bits"], ae_target=0.7, ae_percentile=100.0, texture=0.02)
    x = h.linear_output[0]
    return x / x.max()
