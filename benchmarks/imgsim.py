"""A third, image-based camera simulator (issue 16), held out for scoring only: it renders whole frames and measures
regions with the service's own code, so :func:`illumon.diagnosis.fit.diagnose` receives what the service would store.

Nothing in the diagnosis was chosen on it; it shares no rendering, noise, exposure or rounding code with
:mod:`illumon.simulation.simulate` / :func:`illumon.simulation.effects.hide_effect` or with ``benchmarks/rawsim.py`` (only the
data splits of :mod:`rawsim`: score cameras, score surfaces and score daylight, and the effect *definitions*:
parameter ranges, :func:`illumon.simulation.effects.lamp_spectra` and the fluorophore compilation).

Pipeline, per history (one fixed camera, one scene):

1. **Scene.** A 160 × 120 image: P (8…12) rectangular regions, one measured surface each, laid on a jittered grid
   over a background mixing three surfaces through smooth random fields. Every pixel has a fixed multiplicative
   reflectance texture (a blurred random field, 0…6 % for regions, 10 % for the background). A fixed vignetting
   ``cos⁴ θ`` (corner falloff 55…85 %) is the same in every frame (the camera does not move).
2. **Light → sensor.** Spectral radiance per surface and frame (daylight × reflectance, or an effect's radiance:
   a replaced or soiled surface, a shadow lit by skylight only, lamp light, fluorescent emission) through the
   camera's measured sensitivities (:func:`illumon.simulation.datasets.load_camera`), the shadow as a blurred mask over a
   rectangle around its region (the background near it is shaded too).
3. **Auto-exposure** of its own design: a mean-luminance meter (centre-weighted mean of the white-balanced image to
   a body's target of 12…20 % of white), smoothed in log exposure (a fraction 0.3…0.7 of the error per frame) with a
   hysteresis dead band of 1/8…1/4 stop, exposure continuous (a shutter, no stops), and a highlight guard that caps
   the brightest region's 99th-percentile pixel at 85 % of white (raw and output). ``clipping`` instead exposes
   the brightest region's mean 1.05…1.4 × beyond white in every frame.
4. **Sensor, Bayer RGGB mosaic** (each pixel one channel): Poisson photon shot noise of the electrons (a body's full
   well and conversion gain at ISO 100…1600), dark current (Poisson, 0…8 e⁻ per frame), Gaussian read noise,
   per-row read noise (banding, 0…0.5 DN per frame); the dark current's mean is removed (optical-black clamp), its shot
   noise stays, black level, 12- or 14-bit ADC.
5. **Raw converter:** black subtraction with clipping at 0, demosaicing with OpenCV (``cv2.COLOR_BayerRGGB2RGB``,
   bilinear or edge-aware), white balance by a fixed daylight preset (gains from the camera under CIE D55 with a
   preset error of a few %, constant over frames), an optional mild 3 × 3 colour matrix (half the histories),
   clipping to 0…1, the camera's output encoding (linear, sRGB, a gamma), 8-bit output written as PNG or as a real
   JPEG (``cv2.imencode``, quality 85…95, 4:2:0 chroma).
6. **Measurement:** the image bytes decoded by the service (:func:`illumon_service.decode.decode_image`), the
   regions measured by :func:`illumon_service.regions.region_stats` with the *declared* response curve and the
   service's default clip and region fractions, and the history assembled by
   :func:`illumon_service.estimation.build_observations` (means and their standard errors).

How it differs from the other two: :func:`~illumon.simulation.effects.hide_effect` adds Gaussian noise to region
means with log-normal exposure jitter and full float precision; ``rawsim`` draws per-region pixel lists (no image,
no mosaic, no demosaicing, no vignetting), third-stop percentile auto-exposure and JPEG-*like* DC rounding. Here the
regions are rectangles of a real image: demosaicing mixes neighbouring pixels (and the background into region
edges), white balance gains and a colour matrix precede clipping and 8-bit rounding, JPEG compression and chroma
subsampling are OpenCV's, and clipped and outlying pixels are removed by the service's robust means.

Effects (names of :data:`illumon.simulation.effects.EFFECTS`; ranges of :mod:`illumon.simulation.effects`):
``nonlinear_response`` the camera encodes with sRGB or a gamma 1.5…2.6 the user did not declare (declared linear);
``black_offset`` the converter under-subtracts the black level, leaving 1.5…6 % of the output white per channel;
``clipping`` exposure 1.05…1.4 × beyond white (above); ``patch_change`` a region replaced by another surface or
soiled (darkened 0.5…0.8 and yellowed) from an onset frame; ``shadow`` one region (and its surroundings) lit by
skylight only (CIE daylight 10 000…25 000 K at 15…45 % of the daylight level at 560 nm) for a run of frames ending
inside the history; ``off_locus_illuminant`` 3…F/5 frames lit by a lamp mixed 60…100 % with daylight;
``fluorescence`` one region emits (Han et al., "Camera spectral sensitivity estimation from a single image under
unknown illumination by using fluorescence", CVPR 2012, eqs. 1–2) with a compilation fluorophore, 20…60 % of its
reflected signal in the channel where the emission is strongest. Clean histories declare the curve the camera encodes with.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, field

import cv2
import numpy as np
import rawsim
from illumon.observations import Observations
from illumon.simulation import datasets
from illumon.spectra import WAVELENGTHS
from numpy.typing import NDArray

__all__ = ["WIDTH", "HEIGHT", "ImageHiddenEffect", "body_profile", "hide_effect_img", "encode_output"]

WIDTH, HEIGHT = 160, 120
"""Image size (pixels)."""

CLIP_FRACTION, MIN_FRACTION = 0.98, 0.5
"""The service's defaults (``Settings.clip_fraction``, ``Settings.min_region_fraction``)."""

_I560 = int(np.argmin(np.abs(WAVELENGTHS - 560.0)))


@dataclass
class ImageHiddenEffect:
    """A history rendered as images with one hidden effect (see :func:`hide_effect_img`).

    Attributes
    ----------
    effect, patch, frame, parameters
        The hidden effect, its region and onset frame (``None`` where not located) and its parameters, with the
        pipeline's settings.
    observations
        Region means in the declared linear output space as the service stores them (F × P × 3, NaN where a region
        is mostly clipped), with their standard errors.
    sensitivities
        Effective sensitivities of the output channels (61 × 3): ``CSS · diag(g) · Mᵀ`` (white-balance preset gains
        ``g``, colour matrix ``M`` or identity).
    true_white
        Output of a perfect white diffuser under each frame's light (F × 3, same space and exposure; may exceed 1).
    noiseless
        Region means of the noiseless, unclipped, linear output image (F × P × 3): what a perfect pipeline would give.
    illuminants, reflectances
        The light on each frame (F × 61; lamp-lit where the effect says) and the regions' surfaces before any change
        (P × 61).
    images
        The decoded 8-bit frames (RGB), with ``keep_images``.
    """

    effect: str
    patch: int | None
    frame: int | None
    parameters: dict
    observations: Observations
    sensitivities: NDArray[np.float64]
    true_white: NDArray[np.float64]
    noiseless: NDArray[np.float64]
    illuminants: NDArray[np.float64]
    reflectances: NDArray[np.float64]
    images: list[NDArray[np.uint8]] = field(default_factory=list)


def body_profile(camera: str, iso: float) -> dict:
    """Sensor constants of a simulated body of ``camera`` (stable per name, drawn apart from :mod:`rawsim`'s): full
    well 8 000…40 000 e⁻, read noise 1.5…6 e⁻, a 12- or 14-bit ADC with its black level, dark current, row noise
    and the conversion gain (e⁻/DN) at ``iso`` (base ISO 100 maps the full well to the ADC's white)."""
    h = np.random.default_rng([zlib.crc32(f"imgsim:{camera}".encode()), 7])
    full_well = float(h.uniform(8_000, 40_000))
    adc_bits = int(h.choice([12, 14]))
    black = float(h.choice({12: [64, 128, 200, 256], 14: [512, 800, 1024, 2048]}[adc_bits]))
    white_dn = 2**adc_bits - 1 - black
    return {"full_well_e": full_well, "read_noise_e": float(h.uniform(1.5, 6.0)), "adc_bits": adc_bits,
            "black_level": black, "white_dn": white_dn, "dark_e": float(h.uniform(0.0, 8.0)),
            "row_noise_dn": float(h.uniform(0.0, 0.5)), "iso": iso,
            "conversion_gain": full_well / white_dn / (iso / 100.0), "ae_target": float(h.uniform(0.12, 0.20)),
            "ae_speed": float(h.uniform(0.3, 0.7)), "ae_deadband_stops": float(h.uniform(0.125, 0.25))}


def encode_output(linear: NDArray[np.float64], tone: str | float | None) -> NDArray[np.float64]:
    """The camera's output encoding of linear values (0…1): ``"srgb"`` (IEC 61966-2-1 via colour-science), a gamma
    γ (``x^(1/γ)``) or ``None`` (linear)."""
    x = np.clip(linear, 0.0, 1.0)
    if tone is None:
        return x
    if tone == "srgb":
        import colour

        return np.asarray(colour.models.eotf_inverse_sRGB(x), dtype=float)
    return x ** (1.0 / float(tone))


def _smooth_field(rng: np.random.Generator, sigma: float) -> NDArray[np.float64]:
    """A smooth random field on the image, zero mean, values within about ±1."""
    f = cv2.GaussianBlur(rng.standard_normal((HEIGHT, WIDTH)), (0, 0), sigma)
    return f / max(3.0 * f.std(), 1e-12)


def _vignette(rng: np.random.Generator) -> tuple[NDArray[np.float64], float]:
    """``cos⁴ θ`` falloff about the image centre, the corner at 55…85 % of the centre."""
    corner = float(rng.uniform(0.55, 0.85))
    half_diag = np.hypot(WIDTH / 2, HEIGHT / 2)
    focal = half_diag / np.tan(np.arccos(corner**0.25))
    yy, xx = np.mgrid[0:HEIGHT, 0:WIDTH]
    r = np.hypot(xx + 0.5 - WIDTH / 2, yy + 0.5 - HEIGHT / 2)
    return np.cos(np.arctan(r / focal)) ** 4, corner


def _layout(p: int, rng: np.random.Generator) -> list[tuple[int, int, int, int]]:
    """``p`` non-overlapping rectangles (x, y, width, height) on a jittered 4 × 3 grid of 40 × 40 cells."""
    cells = rng.permutation(12)[:p]
    out = []
    for c in sorted(cells):
        cx, cy = 40 * (c % 4), 40 * (c // 4)
        w, h = int(rng.integers(20, 33)), int(rng.integers(16, 31))
        x, y = cx + int(rng.integers(3, 38 - w)), cy + int(rng.integers(3, 38 - h))
        out.append((x, y, w, h))
    return out


def _wb_gains(css: NDArray[np.float64], rng: np.random.Generator) -> NDArray[np.float64]:
    """A daylight white-balance preset: gains that make the camera's CIE D55 white neutral (green 1), each off by a
    preset error of up to ±4 %."""
    import colour

    sd = colour.SDS_ILLUMINANTS["D55"]
    d55 = np.interp(WAVELENGTHS, sd.wavelengths, sd.values)
    white = d55 @ css
    g = white[1] / white
    return g * np.array([rng.uniform(0.96, 1.04), 1.0, rng.uniform(0.96, 1.04)])


def _matrix(rng: np.random.Generator) -> NDArray[np.float64]:
    """A mild colour matrix (rows sum to 1, off-diagonal −0.02…−0.2): the saturation boost of an output profile."""
    off = -rng.uniform(0.02, 0.2, (3, 3))
    np.fill_diagonal(off, 0.0)
    np.fill_diagonal(off, 1.0 - off.sum(axis=1))
    return off


def _auto_exposure(meter: NDArray[np.float64], peak: NDArray[np.float64], prof: dict, guard: float = 0.85,
                   clip_target: float | None = None) -> NDArray[np.float64]:
    """Output value per unit signal, per frame: the meter reading (mean output at unit exposure) to the body's target,
    smoothed in log exposure with a dead band, then capped so ``peak`` (the brightest region's highlight at unit
    exposure) stays at ``guard`` of white; with ``clip_target``, the brightest region's mean is exposed to that
    multiple of white instead (over-exposure)."""
    if clip_target is not None:
        return clip_target / peak
    want = np.log2(prof["ae_target"] / meter)
    cur = np.empty_like(want)
    cur[0] = want[0]
    for i in range(1, want.size):
        err = want[i] - cur[i - 1]
        cur[i] = cur[i - 1] if abs(err) < prof["ae_deadband_stops"] else cur[i - 1] + prof["ae_speed"] * err
    return np.minimum(2.0**cur, guard / peak)


def hide_effect_img(effect: str, camera: str, seed: int, *, split: str = "score", frames: int | None = None,
                    patches: int | None = None, keep_images: bool = False, jpeg: bool | None = None,
                    tone: str | float | None | bool = False) -> ImageHiddenEffect:
    """A history of ``camera`` with one hidden ``effect``, rendered as images and measured as the service does (module
    docstring).

    Parameters
    ----------
    effect
        One of :data:`illumon.simulation.effects.EFFECTS`.
    camera
        A measured camera (:data:`rawsim.SCORE_CAMERAS` for scoring).
    seed
        Seed of every random choice.
    split
        Surfaces and daylight of :mod:`rawsim`'s ``"score"`` (default) or ``"dev"`` split.
    frames, patches
        History size (default 24…40 frames, 8…12 regions).
    keep_images
        Keep the decoded 8-bit frames (``.images``, RGB).
    jpeg
        Force JPEG (True) or PNG (False) output; default drawn (half the histories).
    tone
        Force the output encoding (declared and used, ``None`` linear, ``"srgb"`` or a gamma) of a history without
        ``nonlinear_response``; default (``False``) drawn.

    Returns
    -------
    ImageHiddenEffect
    """
    from illumon.simulation.effects import (
        EFFECTS,
        _compilation_fluorophores,
        draw_patch_change,
        draw_shadow,
        lamp_spectra,
        soiled,
    )
    from illumon_service.decode import decode_image
    from illumon_service.estimation import build_observations
    from illumon_service.regions import Region, region_stats, response_for

    if effect not in EFFECTS:
        raise ValueError(f"unknown effect {effect!r}; choose from {', '.join(EFFECTS)}")
    rng = np.random.default_rng([seed, zlib.crc32(b"imgsim")])
    f = int(frames or rng.integers(24, 41))
    p = int(patches or rng.integers(8, 13))
    css = datasets.load_camera(camera)
    prof = body_profile(camera, float(rng.choice([100, 200, 400, 800, 1600])))
    e = rawsim.daylight_run(split, f, rng)
    surfaces = rawsim.draw_reflectances(split, p + 4, rng)  # regions, a spare (replacement), three backgrounds
    r, spare = surfaces[:p], surfaces[p]
    bg = surfaces[p + 1 :] * rng.uniform(0.3, 0.8, (3, 1))
    materials = np.vstack([r, bg])  # M × 61
    m_count = materials.shape[0]

    # scene: per-pixel material weights (texture included), fixed over frames
    rects = _layout(p, rng)
    weights = np.zeros((HEIGHT, WIDTH, m_count))
    logits = np.stack([_smooth_field(rng, 12.0) for _ in range(3)], axis=-1) * 4.0
    mix = np.exp(logits - logits.max(axis=-1, keepdims=True))
    weights[..., p:] = mix / mix.sum(axis=-1, keepdims=True) * (1.0 + 0.1 * _smooth_field(rng, 1.0))[..., None]
    texture = float(rng.uniform(0.0, 0.06))
    inside = np.zeros((HEIGHT, WIDTH), dtype=bool)
    for j, (x, y, w, h) in enumerate(rects):
        tex = 1.0 + texture * _smooth_field(rng, float(rng.uniform(0.7, 2.0)))[y : y + h, x : x + w]
        weights[y : y + h, x : x + w, :] = 0.0
        weights[y : y + h, x : x + w, j] = tex
        inside[y : y + h, x : x + w] = True
    vig, corner = _vignette(rng)

    gains = _wb_gains(css, rng)
    matrix = _matrix(rng) if rng.random() < 0.5 else None
    m_eff = np.eye(3) if matrix is None else matrix
    c_eff = css * gains[None, :] @ m_eff.T  # output channels' sensitivities
    declared: str | float | None = [None, "srgb", float(rng.uniform(1.8, 2.4))][int(rng.integers(3))]
    if tone is not False:
        declared = tone
    actual = declared
    drawn_jpeg = bool(rng.random() < 0.5)  # drawn even when forced: the same scene and noise either way
    use_jpeg = drawn_jpeg if jpeg is None else jpeg
    quality = int(rng.integers(85, 96))
    demosaic = cv2.COLOR_BayerRGGB2RGB_EA if rng.random() < 0.5 else cv2.COLOR_BayerRGGB2RGB
    params: dict = {"iso": prof["iso"], "adc_bits": prof["adc_bits"], "jpeg_quality": quality if use_jpeg else None,
                    "declared_tone": declared, "matrix": None if matrix is None else matrix.tolist(),
                    "wb_gains": gains.tolist(), "vignette_corner": corner, "texture": texture,
                    "demosaic": "edge-aware" if demosaic == cv2.COLOR_BayerRGGB2RGB_EA else "bilinear"}

    # spectral radiance per frame and material; the shadow's light and mask
    lit = e.copy()
    rad = e[:, None, :] * materials[None, :, :]
    shade_rad = None
    shade_mask = np.zeros((f, HEIGHT, WIDTH))
    patch: int | None = None
    frame: int | None = None
    black_sub = np.full(3, prof["black_level"])
    clip_target = None
    if effect == "nonlinear_response":
        declared = None
        actual = "srgb" if rng.random() < 0.5 else float(rng.uniform(1.5, 2.6))
        params.update(declared_tone=None, tone=actual)
    elif effect == "black_offset":
        b = rng.uniform(0.015, 0.06, 3)  # of the output white, per output channel before the matrix
        black_sub = prof["black_level"] - b / gains * prof["white_dn"]
        params["offsets"] = b.tolist()
    elif effect == "clipping":
        clip_target = float(rng.uniform(1.05, 1.4))
        params["exposure_beyond_white"] = clip_target
    elif effect == "patch_change":
        patch, frame = draw_patch_change(rng, f, p)
        if rng.random() < 0.5:
            new = spare
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
        shade = level * e[:, _I560 : _I560 + 1] * (sky / sky[_I560])[None]  # F × 61
        shade_rad = shade[:, None, :] * materials[None, :, :]
        x, y, w, h = rects[patch]
        pad = int(rng.integers(2, 5))  # within the ≥ 6 px between regions
        mask = np.zeros((HEIGHT, WIDTH))
        mask[max(0, y - pad) : y + h + pad, max(0, x - pad) : x + w + pad] = 1.0
        mask = cv2.GaussianBlur(mask, (0, 0), 1.5)  # penumbra
        run = np.arange(frame, frame + length)
        shade_mask[run] = mask
        params.update(shaded_frames=run.tolist(), sky_cct=sky_cct, level=level, margin_px=pad)
    elif effect == "off_locus_illuminant":
        n_off = int(rng.integers(3, max(4, f // 5) + 1))
        which = np.sort(rng.choice(f, n_off, replace=False))
        lamps = lamp_spectra()
        name = str(rng.choice(list(lamps)))
        lamp = lamps[name]
        mix_frac = rng.uniform(0.6, 1.0, n_off)
        for i, m in zip(which, mix_frac, strict=True):
            lit[i] = (1 - m) * e[i] + m * lamp * e[i, _I560] / lamp[_I560]
        rad = lit[:, None, :] * materials[None, :, :]
        params.update(frames=which.tolist(), lamp=name, lamp_fraction=mix_frac.tolist())
    elif effect == "fluorescence":
        patch = int(rng.integers(p))
        fl = _compilation_fluorophores()
        name, ex, em = fl[int(rng.integers(len(fl)))]
        emitted = (e @ ex)[:, None] * em[None]  # Han et al. 2012, eqs. 1–2
        refl = rad[:, patch] @ c_eff
        cam_em = emitted @ c_eff
        ch = int(np.argmax(cam_em.sum(0)))
        ratio = float(rng.uniform(0.2, 0.6))
        rad[:, patch] += ratio * np.median(refl[:, ch]) / np.median(cam_em[:, ch]) * emitted
        params.update(fluorophore=name, emission_ratio=ratio, channel=ch)

    # noiseless raw signal per pixel and frame (camera units before exposure), vignetted
    resp = rad @ css  # F × M × 3
    wflat = weights.reshape(-1, m_count)
    signal = np.einsum("nm,fmc->fnc", wflat, resp)
    if shade_rad is not None:
        d = shade_rad @ css - resp
        signal += shade_mask.reshape(f, -1, 1) * np.einsum("nm,fmc->fnc", wflat, d)
    signal = signal.reshape(f, HEIGHT, WIDTH, 3) * vig[None, :, :, None]

    # auto-exposure on the white-balanced, matrixed (noiseless) image
    out_unit = np.einsum("fhwc,dc->fhwd", signal * gains, m_eff)  # output at unit exposure
    lum = out_unit @ np.array([0.25, 0.5, 0.25])
    centre = np.exp(-0.5 * (((np.mgrid[0:HEIGHT, 0:WIDTH][1] - WIDTH / 2) / (WIDTH / 3)) ** 2
                            + ((np.mgrid[0:HEIGHT, 0:WIDTH][0] - HEIGHT / 2) / (HEIGHT / 3)) ** 2))
    meter = (lum * centre).sum(axis=(1, 2)) / centre.sum()
    highlight = np.zeros(f)
    brightest_mean = np.zeros(f)
    for x, y, w, h in rects:
        for img in (out_unit, signal):
            block = img[:, y : y + h, x : x + w].reshape(f, -1)
            highlight = np.maximum(highlight, np.percentile(block, 99.0, axis=1))
        brightest_mean = np.maximum(brightest_mean, out_unit[:, y : y + h, x : x + w].mean(axis=(1, 2)).max(axis=1))
    exposure = _auto_exposure(meter, brightest_mean if clip_target else highlight, prof, clip_target=clip_target)

    # sensor: Bayer RGGB mosaic, electrons, dark current, read and row noise, black level, ADC
    yy, xx = np.mgrid[0:HEIGHT, 0:WIDTH]
    cfa = np.where((yy % 2 == 0) & (xx % 2 == 0), 0, np.where((yy % 2 == 1) & (xx % 2 == 1), 2, 1))
    adc_max = 2 ** prof["adc_bits"] - 1
    gain_e = prof["conversion_gain"]
    white_dn = prof["white_dn"]
    black_sub_px = black_sub[cfa]
    curve = {"encoding": "linear" if declared is None else ("srgb" if declared == "srgb" else "gamma"),
             "gamma": None if declared in (None, "srgb") else float(declared)}  # what the user registers
    region_list = [Region(f"r{j:02d}", *rect) for j, rect in enumerate(rects)]
    rows = []
    images = []
    for i in range(f):
        mean_e = exposure[i] * gain_e * white_dn * np.take_along_axis(signal[i], cfa[..., None], axis=2)[..., 0]
        electrons = rng.poisson(np.clip(mean_e, 0.0, None) + prof["dark_e"]).astype(float)
        electrons = np.minimum(electrons, prof["full_well_e"])
        dn = (electrons - prof["dark_e"]) / gain_e + prof["read_noise_e"] / gain_e * rng.standard_normal(cfa.shape)
        dn += prof["row_noise_dn"] * rng.standard_normal((HEIGHT, 1)) + prof["black_level"]
        raw = np.clip(np.round(dn), 0, adc_max)
        sub = np.clip(np.round(raw - black_sub_px), 0, 65535).astype(np.uint16)  # converter: black, clip at 0
        rgb = cv2.cvtColor(sub, demosaic).astype(float) / white_dn
        out = np.clip(np.einsum("hwc,dc->hwd", rgb * gains, m_eff), 0.0, 1.0)
        codes = np.round(255.0 * encode_output(out, actual)).astype(np.uint8)
        bgr = np.ascontiguousarray(codes[:, :, ::-1])
        ok, data = (cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, quality]) if use_jpeg
                    else cv2.imencode(".png", bgr))
        assert ok
        image, full = decode_image(data.tobytes())
        if keep_images:
            images.append(np.ascontiguousarray(image))
        stats = region_stats(image, region_list, response_for(curve, full), clip_fraction=CLIP_FRACTION,
                             min_fraction=MIN_FRACTION)
        rows.append((f"f{i:05d}", "", {k: None if v is None else v[0] for k, v in stats.items()},
                     {k: None if v is None else v[1] for k, v in stats.items()}))
    obs = build_observations(rows, [reg.id for reg in region_list])
    out_lin = out_unit * exposure[:, None, None, None]
    noiseless = np.stack([out_lin[:, y : y + h, x : x + w].mean(axis=(1, 2)) for x, y, w, h in rects], axis=1)
    true_white = exposure[:, None] * (lit @ c_eff)
    params.update(exposure=exposure.tolist(), jpeg=use_jpeg)
    return ImageHiddenEffect(effect, patch, frame, params, obs, c_eff, true_white, noiseless, lit, r, images)
