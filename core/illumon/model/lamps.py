"""Light that is not daylight: each frame's posterior probability ``non_daylight`` and a general-illuminant white.

The scene model explains every frame by a daylight (:mod:`.fit`). Frames lit wholly or partly by lamps — street lamps
at dusk, car parks, lit signs, a ceiling light beside a window — are not daylight, and forcing them onto the daylight
locus moves their white by many degrees and bends the reflectances learned from them. This module compares, for every
frame, two hypotheses about its camera white ``u`` (log r/g, log b/g):

* **daylight** (``D``): ``u`` is the white of a CIE daylight through the camera, reciprocal temperature and offset from
  the locus under the model's own prior (:class:`illumon.daylight.CIEDaylight`);
* **not daylight** (``L``): ``u`` is the white of a lamp — the CIE fluorescent, high-pressure and LED illuminants and
  CIE A (incandescent), alone or mixed half and half with daylight — through the same camera.

The data that speak to ``u`` without any daylight assumption are the frame's scene average: a static scene's average
colour is common to every frame, so ``u_f = log chroma(mean of frame f's patches) − a`` with one unknown offset ``a``
for the whole history (gray-world made Bayesian, Buchsbaum 1980). ``a`` has a Gaussian prior: the mean measured
surface's colour under the daylight prior's mean, towards grey as far as the patches barely differ
(:func:`expected_scene_offset`), spread :data:`SCENE_OFFSET_SD` (plus the camera's own white uncertainty for a camera
nobody measured); without a model (:func:`lamp_posterior` called on its own) grey. The posterior
over ``a`` (a grid) given every frame's two-hypothesis mixture gives each frame's posterior ``non_daylight``; in a
history with daylight frames those pin ``a``, so a frame whose light departs from them as no daylight does is called a
lamp. In a history at least half daylight, the frames whose data favour a lamp are left out of the reflectance fit
(:func:`illumon.model.fit_scene_model`) and a frame with ``non_daylight`` > 0.5 takes the white of a *general*
illuminant fitted to the reflectances learned under daylight (:func:`.general.general_whites`); elsewhere the frames are
reported and keep the daylight fit's white.

References
----------
.. [Buchsbaum1980] Buchsbaum, 1980.
.. [CIE015] CIE 015:2018: illuminant A and the F, HP and LED illuminant tables (via colour-science).
.. [Marguier2007] Marguier & Süsstrunk, CIC 2007: the daylight model this module tests frames against.
.. [Kinoshita2023] Kinoshita & Kiya, 2023: the linear Gaussian posterior, eqs. 13–14, used for the general
   illuminant.
.. [Keys1981] Keys, 1981: cubic convolution (a = −½), the interpolation between the lattice nodes of
   :func:`lamp_posterior`'s tables.
"""

from __future__ import annotations

import math
import threading
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray
from scipy import fft as sp_fft
from scipy.interpolate import RegularGridInterpolator
from scipy.special import ndtri

from .._blas import single_blas_thread
from .._tables import cached_arrays
from ..camera.formation import Z95
from ..daylight import CIEDaylight
from ..observations import observed
from ..priors import ReflectanceBasis, reflectance_basis
from ..priors.scene_average import expected_offset, log_chroma, scene_average_evidence
from .general import cie_lamp_spectra, general_whites

__all__ = [
    "LAMP_PRIOR",
    "MIN_DAYLIGHT_FRAMES",
    "SCENE_OFFSET_SD",
    "FRAME_SD",
    "LampPosterior",
    "lamp_posterior",
    "expected_scene_offset",
    "frame_lamp_posterior",
    "lamp_population",
    "HistoryJudgement",
    "history_lamps",
    "apply_lamps",
    "unbalanced_probability",
    "log_chroma_confidence",
    "non_daylight_column",
    "frame_verdicts",
    "EVIDENCE_FRAMES",
    "evidence_frames",
]

MIN_DAYLIGHT_FRAMES = 6
"""Daylight frames a history needs before a lamp-lit frame's white is taken from the reflectances learned under them
(:func:`.general.general_whites`): the reflectances of a static scene are not determined by two or three lights. On the
development real photographs (``sony-isp-auto`` of ``benchmarks/real.py``: three frames, a camera that balances itself,
two judged daylight) the spectral white of the third frame was 21° off where the daylight fit's was 8.4°; with the
greys known, the whole set's median stays 3.0° either way."""

LAMP_PRIOR = 0.25
"""Prior probability that a frame's light is not daylight: the largest (on a 0.05 grid) that flags no frame of the
development indoor photographs (the ``sony-dolp`` chart sets of ``benchmarks/real.py``: rooms lit through windows and
by ceiling lamps, light not measured: the choice takes light a camera reads as near daylight not to be flagged; at 0.3
one frame of each rendered set reached 0.54–0.56), ``python benchmarks/lamps.py``. Kept when the offset's prior moved
to where measured surfaces average (:func:`expected_scene_offset`), though those photographs then read 0.02–0.19 and
0.35 would leave them 0.30: at 0.35 the test of a camera nobody measured judged 12–30 of 30 frames of rendered
daylight read as sensor RGB lamp-lit on their own (0–2 at 0.25; ``tests/core/diagnosis/test_lamp_history.py``,
development ``benchmarks/unmeasured.py`` histories)."""

SCENE_OFFSET_SD = 0.155
"""Standard deviation (log r/g and b/g) of a scene's average colour about the mean measured surface's under the same
light (:data:`illumon.camera.calibration.SCENE_AVERAGE_SD`: 280 development scenes of ten measured surfaces;
:func:`expected_scene_offset`)."""

FRAME_SD = 0.02
"""Per-frame scatter (log units) of a frame's scene-average chroma about ``u + a``: measurement noise, parts of the
scene whose light differs from the frame's (shade, reflections) and the CIE model's departure from a measured sky."""

_MIX = (1.0, 0.5)  # lamp share of the light: the lamp alone, or half and half with daylight
MIX_DAYLIGHTS = 3
"""Daylights a lamp is mixed with half and half: this many quantiles of the daylight prior's reciprocal temperature
(the daylight in a mixed light is as uncertain as a daylight frame's). With the prior's mean alone every mixed lamp
sat by the commonest daylight white, where a daylight frame then read as more probably a lamp: on the development split
(``python benchmarks/unmeasured.py --split dev --seeds 2``) 7–14 % of the frames of rendered daylight histories
(``none+rendered``, ``grey+rendered``) read ``non_daylight`` ≥ 0.5, 1–9 % with three; lamp-lit histories stay flagged
(``none+lamps``, every frame). On the development cameras of the effect simulator (daylight mixed 35–80 % with a lamp
in some frames, measured sensitivities) the lamp-lit frames flagged stay 90 %, the whites gain (lamp-lit frames'
median error 2.11° → 1.29°, daylight frames' 2.09° → 0.85°, mean over six histories:
``python tools/lamp_mixing.py --mix-daylights 1`` and ``3``). Seven quantiles flagged fewer of those lamp-lit
frames on a test camera."""
_LAMP_SD = 0.03  # spread of a lamp type's white (manufacturing, ageing; log units)


_POPULATIONS_KEPT = 8  # cameras × daylight priors whose populations are remembered
_TABLES_KEPT = 8  # lattice tables remembered (a few MiB at most)
_cache_lock = threading.Lock()
_populations: OrderedDict[tuple, tuple[NDArray[np.float64], ...]] = OrderedDict()
_tables: OrderedDict[tuple, NDArray[np.float64]] = OrderedDict()


def _remember(cache: OrderedDict, key: tuple, value: object, size: int = _POPULATIONS_KEPT) -> None:
    """Keep ``value`` under ``key``, forgetting the least recently used entries beyond ``size``."""
    with _cache_lock:
        cache[key] = value
        cache.move_to_end(key)
        while len(cache) > size:
            cache.popitem(last=False)


def _recall(cache: OrderedDict, key: tuple) -> object | None:
    """The value kept under ``key``, or ``None``."""
    with _cache_lock:
        value = cache.get(key)
        if value is not None:
            cache.move_to_end(key)
        return value


def _daylight_grid(dm: CIEDaylight) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(mired, δ) grid over the model's bounds and its normalised log prior weights."""
    lo, hi = dm.bounds()
    mired = np.arange(lo[0], hi[0] + 1e-9, 4.0)
    deltas = np.array([-2.0, -1.0, 0.0, 1.0, 2.0]) * dm.duv_sigma
    m, d = np.meshgrid(mired, deltas, indexing="ij")
    theta = np.stack([m.ravel(), d.ravel()], axis=1)
    logw = -0.5 * ((theta[:, 0] - dm.mired_mean) / dm.mired_sigma) ** 2 - 0.5 * (theta[:, 1] / max(dm.duv_sigma, 1e-9)) ** 2
    return theta, logw - np.logaddexp.reduce(logw)


def lamp_population(
    sensitivities: NDArray[np.float64], daylight: CIEDaylight | None = None, mix_daylights: int = MIX_DAYLIGHTS,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """The two hypotheses' whites through a camera, as log chroma (r/g, b/g).

    Returns the daylight whites (N × 2) with their log prior weights (N,), and the lamp whites (M × 2) with theirs:
    every lamp of the CIE tables alone and half and half with daylight at ``mix_daylights`` quantiles of the prior's
    reciprocal temperature (each share half the weight; one: the prior's mean).
    """
    return tuple(v.copy() for v in _population(sensitivities, daylight or CIEDaylight(), mix_daylights))


def _population(sensitivities: NDArray[np.float64], dm: CIEDaylight,
                mix_daylights: int = MIX_DAYLIGHTS) -> tuple[NDArray[np.float64], ...]:
    """:func:`lamp_population`, read-only, remembered for the last few cameras and CIE daylight priors (a new frame's
    estimate judges it against them: a third of the lamp test's time per frame)."""
    css = np.asarray(sensitivities, dtype=float)
    key = None
    if type(dm) is CIEDaylight:
        key = (css.shape, css.tobytes(), dm.duv_sigma, dm.mired_mean, dm.mired_sigma, mix_daylights)
        hit = _recall(_populations, key)
        if hit is not None:
            return hit
    theta, logw_d = _daylight_grid(dm)
    day = dm.spectra(theta)
    u_d = log_chroma(day @ css)
    lamps = cie_lamp_spectra()
    rows, logw = [], []
    for share in _MIX:
        # each share weighs the same; a mixed lamp's daylight is one of the prior's quantiles (equal weights)
        mired = [dm.mired_mean] if share == 1.0 else (
            dm.mired_mean + dm.mired_sigma * ndtri((np.arange(mix_daylights) + 0.5) / mix_daylights))
        for m in mired:
            d = dm.spectra(np.array([[m, 0.0]]))[0]
            # equal luminance-like weight at 560 nm: both spectra are 100 there
            rows.append(share * lamps + (1.0 - share) * d[None, :] * 100.0 / d[32])
            logw.append(np.full(len(lamps), -math.log(len(_MIX) * len(mired) * len(lamps))))
    u_l = log_chroma(np.concatenate(rows) @ css)
    logw_l = np.concatenate(logw)
    out = (u_d, logw_d, u_l, logw_l)
    for v in out:
        v.flags.writeable = False
    if key is not None:
        _remember(_populations, key, out)
    return out


@dataclass
class LampPosterior:
    """Per-frame result of :func:`lamp_posterior`.

    Attributes
    ----------
    non_daylight
        Posterior probability (F,) that the frame's light is not daylight.
    white
        General-illuminant camera white of every frame (F × 3, green = 1): the frame's scene average over the
        history's scene-average colour.
    offset, offset_sd
        Posterior mean and standard deviation (log r/g, b/g) of the scene's average colour relative to the light.
    """

    non_daylight: NDArray[np.float64]
    white: NDArray[np.float64]
    offset: NDArray[np.float64]
    offset_sd: NDArray[np.float64]


TABLE_STEP = 0.4
"""Largest step of the regular lattices the two mixtures' log densities are tabulated on, in units of the mixture's
standard deviation (:data:`FRAME_SD` for :func:`lamp_posterior`). :func:`lamp_posterior` interpolates its exact table
by cubic convolution, whose error is third order in the step: on 48 random histories of 1–2 000 frames (three
measured cameras, lamp shares 0–60 %, some frames far off) its ``non_daylight`` stayed within 3.6e-4 and its offset
within 2.0e-5 of the exact computation, where bilinear tables of this step erred by up to 1.5e-2
(``tests/core/model/test_lamps.py`` checks four). :func:`_mixture_loglik` interpolates bilinearly (about step²/8 ≈
0.02 nats)."""

TABLE_MAX_SIDE = 512
"""Points per axis of :func:`_mixture_loglik`'s table at most (a wider span takes a coarser step)."""

WINDOW_SIDE = 384
"""Lattice nodes per axis :func:`lamp_posterior` spends on the frames' own spread of log chromaticity, beside the
offset grid's span: about 3 log units at the usual step. Frames outside the window holding the most frames (a channel
near zero) are judged pair by pair (:func:`_pairwise`), so the lattice stays bounded whatever the frames."""

BLOCK_EXPONENT = 300.0
"""Largest exponent of the separable factors :func:`_lattice_logdensity` multiplies (per axis): their products stay
within e^±600, inside double precision, so nothing overflows and no centre's leading term underflows."""

TILE = 32
"""Lattice nodes per axis a table's range is rounded out to (:func:`_lattice_table`): rounds of a refit whose frames
moved a little get the same table."""

CHUNK_POINTS = 1 << 20
"""Frame × offset pairs evaluated at once where :func:`lamp_posterior` visits pairs one by one (each frame's lamp
share over the offset posterior's support, frames outside the lattice)."""


_EXACT_CHUNK = 256
"""Points :func:`_exact_loglik` evaluates at once. Every point's value is computed on its own (its row of the
temporaries), so the chunk changes no value; 256 points × ~450 centres keep the temporaries within ~2 MB, where 4 096
made ~30 MB ones that a fresh process page-faulted in (a 2k refit's per-frame lamp test: ~25 ms more in a fresh
process than in the next refit; 10.8 → 9.3 ms a call once warm; issue 29)."""


def _exact_loglik(u: NDArray[np.float64], centres: NDArray[np.float64], logw: NDArray[np.float64],
                  sd: float) -> NDArray[np.float64]:
    """log Σ_j w_j N(u; c_j, sd² I) at every point of ``u`` (… × 2), centre by centre (the log-sum-exp in numpy:
    scipy's costs 0.5 ms a call, a new frame's estimate makes two)."""
    norm = -math.log(2 * math.pi * sd**2)
    uu = u.reshape(-1, 2)
    out = np.empty(len(uu))
    c0, c1 = np.ascontiguousarray(centres[:, 0]), np.ascontiguousarray(centres[:, 1])
    for i in range(0, len(uu), _EXACT_CHUNK):
        # logw − ((u₀ − c₀)² + (u₁ − c₁)²) / (2 sd²) a coordinate at a time, in place: the same operations in the
        # same order as summing the squared differences' last axis (of length 2), without the points × centres × 2
        # temporaries (1.6 × faster on the 2k refit benchmark's frames, 5 × on 2 000 points and 450 centres)
        x = uu[i:i + _EXACT_CHUNK, 0, None] - c0
        x *= x
        d1 = uu[i:i + _EXACT_CHUNK, 1, None] - c1
        d1 *= d1
        x += d1
        x *= 0.5 / sd**2
        np.subtract(logw, x, out=x)
        top = x.max(axis=1)
        x -= top[:, None]
        np.exp(x, out=x)
        out[i:i + _EXACT_CHUNK] = np.log(x.sum(axis=1)) + top + norm
    return out.reshape(u.shape[:-1])


def _mixture_loglik(u: NDArray[np.float64], centres: NDArray[np.float64], logw: NDArray[np.float64],
                    sd: float) -> NDArray[np.float64]:
    """log Σ_j w_j N(u; c_j, sd² I) for u (… × 2): exact for a few points; for more points than a table over their
    span would hold (a long history's frames), interpolated (bilinear) from the exact values on a regular grid of step
    :data:`TABLE_STEP` · ``sd``."""
    uu = u.reshape(-1, 2)
    return _mixture_density(uu.min(axis=0), uu.max(axis=0), len(uu), centres, logw, sd)(u)


def _mixture_density(lo: NDArray[np.float64], hi: NDArray[np.float64], n_points: int, centres: NDArray[np.float64],
                     logw: NDArray[np.float64], sd: float, per_node: float = 4.0,
                     ) -> Callable[[NDArray[np.float64]], NDArray[np.float64]]:
    """:func:`_mixture_loglik` as a function of ``u`` (… × 2) for ``n_points`` points spanning ``lo`` … ``hi``: the
    table is built once (when there are more than ``per_node`` points per table node), so the points can be
    evaluated a chunk at a time."""
    hi = np.maximum(hi, lo + TABLE_STEP * sd)  # points that share a coordinate: a table still needs a span there
    side = np.minimum(np.ceil((hi - lo) / (TABLE_STEP * sd)).astype(int) + 2, TABLE_MAX_SIDE)
    if n_points > per_node * int(np.prod(side)):
        axes = [np.linspace(lo[i], hi[i], int(side[i])) for i in range(2)]
        interp = RegularGridInterpolator(axes, _lattice_logdensity(axes, centres, logw, sd))
        return lambda u: interp(u.reshape(-1, 2)).reshape(u.shape[:-1])
    return lambda u: _exact_loglik(u, centres, logw, sd)


def _cells(centres: NDArray[np.float64], side: float) -> list[NDArray[np.int64]]:
    """The centres grouped by the square of side ``side`` (a regular grid anchored at their lower corner) each falls
    in."""
    cell = np.floor((centres - centres.min(axis=0)) / side).astype(np.int64)
    _, which = np.unique(cell[:, 0] * (int(cell[:, 1].max()) + 1) + cell[:, 1], return_inverse=True)
    return [np.flatnonzero(which == k) for k in range(int(which.max()) + 1)]


def _lattice_logdensity(axes: list[NDArray[np.float64]], centres: NDArray[np.float64], logw: NDArray[np.float64],
                        sd: float) -> NDArray[np.float64]:
    """log Σ_j w_j N(u; c_j, sd² I) at every node of the lattice ``axes[0] × axes[1]``, exact to rounding at any
    distance from the centres.

    The centres are grouped in small boxes (:func:`_cells`). For a box of centre ``r``, ``|u − c|² = |u − r|² −
    2 (u − r)·(c − r) + |c − r|²``, so its sum is ``exp(−|u − r|² / 2sd²)`` times ``Σ_j v_j exp((x − r₁)(c_j₁ −
    r₁)/sd²) exp((y − r₂)(c_j₂ − r₂)/sd²)``: one matrix product of two small tables (nodes of an axis × centres of the
    box). Boxes are small enough that no factor's exponent exceeds :data:`BLOCK_EXPONENT` in size, so nothing
    overflows and the leading term never underflows; the boxes' log sums are added in log space. The cost is nodes ×
    boxes instead of nodes × centres exponentials.
    """
    x, y = (np.asarray(a, dtype=float) for a in axes)
    inv = 1.0 / sd**2
    span = np.max(np.maximum([x[-1], y[-1]], centres.max(axis=0)) - np.minimum([x[0], y[0]], centres.min(axis=0)))
    out, low = np.full((len(x), len(y)), -np.inf), np.empty((len(x), len(y)))
    for sel in _cells(centres, 2 * BLOCK_EXPONENT / (inv * max(float(span), 1e-12))):
        r = 0.5 * (centres[sel].min(axis=0) + centres[sel].max(axis=0))
        dc = centres[sel] - r
        lv = logw[sel] - 0.5 * inv * (dc**2).sum(axis=1)
        top = float(lv.max())
        dx, dy = x - r[0], y - r[1]
        fx = np.exp(np.outer(dx, dc[:, 0] * inv) + (lv - top))
        fy = np.exp(np.outer(dy, dc[:, 1] * inv))
        block = np.log(fx @ fy.T)
        block -= (0.5 * inv * dx**2 - top)[:, None]
        block -= (0.5 * inv * dy**2)[None, :]
        # out = logaddexp(out, block), in vectorised steps (three times numpy's logaddexp's speed)
        np.minimum(out, block, out=low)
        np.maximum(out, block, out=out)
        low -= out
        np.exp(low, out=low)
        low += 1.0
        out += np.log(low, out=low)
    return out - math.log(2 * math.pi * sd**2)


def _correlate_valid(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """``scipy.signal.correlate(a, b, mode="valid", method="fft")`` of two 2-D arrays, computed as SciPy does it
    (``fftconvolve`` with ``b`` reversed: real FFTs padded to fast lengths, the valid part of the full convolution) —
    the same values, bit for bit, for arrays at least 2 long on each axis (SciPy multiplies a length-1 axis without an
    FFT; the lattice's cubic weights span 4), without importing ``scipy.signal`` and ``scipy.stats`` (~0.3 s of every
    process's start)."""
    full = [sa + sb - 1 for sa, sb in zip(a.shape, b.shape, strict=True)]
    fshape = [sp_fft.next_fast_len(n, True) for n in full]
    spectrum = sp_fft.rfftn(a, fshape) * sp_fft.rfftn(np.ascontiguousarray(b[::-1, ::-1]), fshape)
    out = sp_fft.irfftn(spectrum, fshape)
    valid = [sa - sb + 1 for sa, sb in zip(a.shape, b.shape, strict=True)]
    start = [(n - v) // 2 for n, v in zip(full, valid, strict=True)]
    return out[start[0]:start[0] + valid[0], start[1]:start[1] + valid[1]].copy()


def _lattice_table(centres: NDArray[np.float64], logw: NDArray[np.float64], sd: float, step: NDArray[np.float64],
                   start: NDArray[np.int64], count: NDArray[np.int64]) -> NDArray[np.float64]:
    """:func:`_lattice_logdensity` on the nodes ``(start + i) · step``, ``i < count`` (per axis), computed on the
    range widened to whole multiples of :data:`TILE` nodes and remembered (the last :data:`_TABLES_KEPT`): a refit
    judges its history several times with the same camera, prior and lattice step over almost the same nodes. The
    range computed depends on the request alone, so an answer never depends on what was computed before. A table
    computed by an earlier process on this machine is read from the disk cache (:mod:`illumon._tables`), bit for bit."""
    lo, hi = start // TILE * TILE, ((start + count - 1) // TILE + 1) * TILE
    key = (centres.tobytes(), logw.tobytes(), float(sd), step.tobytes(), lo.tobytes(), hi.tobytes())
    table = _recall(_tables, key)
    if table is None:
        (table,) = cached_arrays(  # read from disk when a process computed it before (issue 29: 15–45 ms each)
            "lamp-lattice", (*key, str(centres.shape)), (__file__,),
            lambda: (_lattice_logdensity([np.arange(lo[i], hi[i]) * step[i] for i in range(2)], centres, logw, sd),))
        table.flags.writeable = False
        _remember(_tables, key, table, _TABLES_KEPT)
    offset = start - lo
    return table[offset[0]:offset[0] + count[0], offset[1]:offset[1] + count[1]]


def _cubic_weights(t: NDArray[np.float64]) -> NDArray[np.float64]:
    """Cubic-convolution weights (Keys, a = −½) of the nodes ``⌊p⌋ − 1 … ⌊p⌋ + 2`` for fractional parts ``t`` of
    positions ``p`` (… × 4): they sum to one and reproduce quadratics exactly."""
    d = np.abs(np.asarray(t, dtype=float)[..., None] - np.array([-1.0, 0.0, 1.0, 2.0]))
    return np.where(d <= 1.0, (1.5 * d - 2.5) * d * d + 1.0, ((-0.5 * d + 2.5) * d - 4.0) * d + 2.0)


def _densest_window(values: NDArray[np.float64], width: float) -> NDArray[np.bool_]:
    """Which ``values`` fall in the interval of length ``width`` that holds the most of them."""
    s = np.sort(values)
    if s[-1] - s[0] <= width:
        return np.ones(len(values), dtype=bool)
    counts = np.searchsorted(s, s + width, side="right") - np.arange(len(s))
    lo = s[int(np.argmax(counts))]
    return (values >= lo) & (values <= lo + width)


class _Lattice:
    """Frames placed on a regular lattice in ``u = g − a`` whose step ``h`` divides the offset grid's (``m`` nodes per
    grid step; nodes at whole multiples of ``h``), with the hypotheses' exact log densities on it
    (:func:`_lattice_table`) and each frame's cubic-convolution weights of its 4 × 4 nearest nodes.

    Moving ``a`` one grid step moves every frame ``m`` whole nodes, so a frame's weights are the same at every ``a``:
    the sum over frames of an interpolated function of ``g_f − a_k`` is the cross-correlation of the frames' weights
    deposited on the lattice with the function's table (:meth:`log_evidence`).
    """

    def __init__(self, g: NDArray[np.float64], a_lo: NDArray[np.float64], a_hi: NDArray[np.float64],
                 step: NDArray[np.float64], m: NDArray[np.int64], hypotheses: list[tuple]) -> None:
        first = np.floor((g.min(axis=0) - a_hi) / step).astype(np.int64) - 2  # lattice index of the first node
        p = (g - a_lo) / step - first  # frame f's position against a_lo; against grid point k: p − k·m
        self.base = np.floor(p).astype(np.int64)
        count = self.base.max(axis=0) + 3
        self.w0 = _cubic_weights(p[:, 0] - self.base[:, 0])
        self.w1 = _cubic_weights(p[:, 1] - self.base[:, 1])
        self.m = m
        self.tables = [_lattice_table(c, w, s, step, first, count) + log_prior for c, w, s, log_prior in hypotheses]

    def log_evidence(self, grid: int) -> NDArray[np.float64]:
        """Σ_f log(prior-weighted mixture of both hypotheses) at every point of the offset grid (grid² values, its
        order): ``Σ_f φ(g_f − a_k) = Σ_l H[l] φ[l − k·m]``, ``H`` the frames' weights deposited on the lattice."""
        base, m = self.base, self.m
        lo = base.min(axis=0) - 1
        size = np.array(self.tables[0].shape) - lo
        rows = (base[:, 0] - 1 - lo[0])[:, None] + np.arange(4)
        cols = (base[:, 1] - 1 - lo[1])[:, None] + np.arange(4)
        weights = np.bincount((rows[:, :, None] * size[1] + cols[:, None, :]).ravel(),
                              (self.w0[:, :, None] * self.w1[:, None, :]).ravel(),
                              minlength=int(size[0] * size[1])).reshape(size)
        span = (grid - 1) * m
        phi = np.logaddexp(*self.tables)[lo[0] - span[0]:, lo[1] - span[1]:]
        corr = _correlate_valid(phi, weights)  # corr[t] = Σ_l H[l] φ[l − (span − t)]
        total = corr[::max(int(m[0]), 1), ::max(int(m[1]), 1)][::-1, ::-1]
        return np.broadcast_to(total, (grid, grid)).reshape(-1)

    def lamp_share(self, points: NDArray[np.int64], weights: NDArray[np.float64]) -> NDArray[np.float64]:
        """Each frame's posterior lamp share averaged over the offset grid points ``points`` (K × 2 indices) with
        ``weights`` (K,)."""
        shift = points * self.m
        out = np.empty(len(self.base))
        step = max(1, CHUNK_POINTS // (16 * len(points)))
        for i in range(0, len(out), step):
            r = slice(i, i + step)
            i0 = (self.base[r, None, 0] - shift[None, :, 0] - 1)[..., None] + np.arange(4)  # frames × K × 4
            i1 = (self.base[r, None, 1] - shift[None, :, 1] - 1)[..., None] + np.arange(4)
            at = (i0[..., :, None], i1[..., None, :])
            vd, vl = (np.einsum("fi,fkij,fj->fk", self.w0[r], t[at], self.w1[r]) for t in self.tables)
            out[r] = np.exp(vl - np.logaddexp(vd, vl)) @ weights
        return out


def _pairwise(g: NDArray[np.float64], a: NDArray[np.float64], hypotheses: list[tuple], *, evidence: bool,
              weights: NDArray[np.float64] | None = None) -> NDArray[np.float64]:
    """Frames ``g`` judged at every offset ``a`` pair by pair against the mixtures (:func:`_mixture_density`: exact for
    fewer pairs than half the nodes of a table over their span, else that table, bilinearly): with ``evidence`` the
    summed log evidence at every ``a`` (as :meth:`_Lattice.log_evidence`), else each frame's lamp share averaged over
    ``a`` with ``weights``."""
    lo, hi, n = g.min(axis=0) - a.max(axis=0), g.max(axis=0) - a.min(axis=0), len(g) * len(a)
    dens = [(_mixture_density(lo, hi, n, c, w, s, per_node=0.5), log_prior) for c, w, s, log_prior in hypotheses]
    total, share = np.zeros(len(a)), np.empty(len(g))
    step = max(1, CHUNK_POINTS // len(a))
    for i in range(0, len(g), step):
        u = g[i:i + step, None, :] - a[None, :, :]
        vd, vl = (d(u) + log_prior for d, log_prior in dens)
        if evidence:
            total += np.logaddexp(vd, vl).sum(axis=0)
        else:
            share[i:i + step] = np.exp(vl - np.logaddexp(vd, vl)) @ weights
    return total if evidence else share


@single_blas_thread
def lamp_posterior(
    means: NDArray[np.float64],
    sensitivities: NDArray[np.float64],
    daylight: CIEDaylight | None = None,
    *,
    camera_sd: float = 0.0,
    prior: float = LAMP_PRIOR,
    offset_prior: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None,
    grid: int = 41,
) -> LampPosterior:
    """Posterior ``non_daylight`` of every frame and its general-illuminant white (module docstring).

    Parameters
    ----------
    means
        Each frame's scene average (F × 3, linear; the same patches in every frame, missing ones filled from the
        model), NaN for frames without one.
    sensitivities
        The camera's (effective) sensitivities, 61 × 3, in the observations' output space.
    daylight
        The daylight model and prior the frames are tested against.
    camera_sd
        The camera white's own uncertainty (log units; an unmeasured camera's spread), common to every frame.
    prior
        Prior probability that a frame is not daylight.
    offset_prior
        Mean and standard deviation (2,) of the scene-average offset ``a``; default grey ± :data:`SCENE_OFFSET_SD`
        widened by ``camera_sd``; a fitted model's history passes :func:`expected_scene_offset` with that spread
        (:func:`history_lamps`), or the level's offset for a history lit only by lamps.
    grid
        Points per axis of the grid over ``a`` (±4 prior standard deviations).

    Notes
    -----
    Every frame's evidence depends on ``u = g_f − a`` only (``g_f`` its log chromaticity), so the two mixtures' log
    densities are tabulated once, exactly (:func:`_lattice_logdensity`), on a regular lattice in ``u`` whose step
    divides the offset grid's (at most :data:`TABLE_STEP` · :data:`FRAME_SD`): moving ``a`` one grid step moves every
    frame a whole number of nodes. With cubic-convolution interpolation between nodes, a frame's log evidence at any
    ``a`` is a fixed 4 × 4 weighting of table values around its own position, so the sum over frames (the offset's
    log posterior) is the cross-correlation of the frames' weights deposited on the lattice with the table, one FFT
    for every ``a`` at once. Each frame's lamp share is then averaged over the offset posterior's support (the grid
    points holding all but 1e-15 of it: one or a few for a long history), from the same interpolated tables.
    """
    dm = daylight or CIEDaylight()
    means = np.asarray(means, dtype=float)
    f = len(means)
    ok = np.all(np.isfinite(means), axis=1) & np.all(means > 0, axis=1)
    g = np.full((f, 2), np.nan)
    g[ok] = log_chroma(means[ok])
    if offset_prior is None:
        s = math.hypot(SCENE_OFFSET_SD, camera_sd)
        mu, sd = np.zeros(2), np.array([s, s])
    else:
        mu, sd = (np.asarray(v, dtype=float) for v in offset_prior)
    u_d, logw_d, u_l, logw_l = _population(sensitivities, dm)
    ax = [np.linspace(mu[i] - 4 * sd[i], mu[i] + 4 * sd[i], grid) for i in range(2)]
    aa = np.stack(np.meshgrid(ax[0], ax[1], indexing="ij"), axis=-1).reshape(-1, 2)  # A × 2
    log_prior_a = -0.5 * (((aa - mu) / sd) ** 2).sum(1)
    nd = np.full(f, np.nan)
    white = np.full((f, 3), np.nan)
    if not ok.any():
        return LampPosterior(nd, white, mu, sd)
    gk = g[ok]
    hypotheses = [(u_d, logw_d, FRAME_SD, math.log(1 - prior)),
                  (u_l, logw_l, math.hypot(FRAME_SD, _LAMP_SD), math.log(prior))]
    # the lattice step: the offset grid's step over m, at most TABLE_STEP · FRAME_SD
    da = np.array([ax[i][1] - ax[i][0] if grid > 1 else 0.0 for i in range(2)])
    m = np.where(da > 0, np.ceil(da / (TABLE_STEP * FRAME_SD)), 0).astype(np.int64)
    h = np.where(m > 0, da / np.maximum(m, 1), TABLE_STEP * FRAME_SD)
    inside = _densest_window(gk[:, 0], WINDOW_SIDE * h[0]) & _densest_window(gk[:, 1], WINDOW_SIDE * h[1])
    lattice = _Lattice(gk[inside], aa[0], aa[-1], h, m, hypotheses) if inside.any() else None
    outside = np.flatnonzero(~inside)
    # pass 1: the offset's posterior, every frame's evidence summed
    total = lattice.log_evidence(grid) if lattice is not None else np.zeros(len(aa))
    if len(outside):
        total = total + _pairwise(gk[outside], aa, hypotheses, evidence=True)
    log_post = log_prior_a + total
    post = np.exp(log_post - log_post.max())
    post /= post.sum()
    # pass 2: each frame's lamp share averaged over that posterior, on its support (all but 1e-15 of it)
    support = np.flatnonzero(~(post <= 1e-15))
    share = np.empty(len(gk))
    if lattice is not None:
        share[inside] = lattice.lamp_share(np.stack(np.unravel_index(support, (grid, grid)), axis=-1), post[support])
    if len(outside):
        share[outside] = _pairwise(gk[outside], aa[support], hypotheses, evidence=False, weights=post[support])
    nd[ok] = share
    a_hat = post @ aa
    a_sd = np.sqrt(np.clip(post @ (aa - a_hat) ** 2, 0, None))
    ug = g[ok] - a_hat
    w = np.ones((int(ok.sum()), 3))
    w[:, 0], w[:, 2] = np.exp(ug[:, 0]), np.exp(ug[:, 1])
    white[ok] = w
    return LampPosterior(nd, white, a_hat, a_sd)


def frame_lamp_posterior(
    means: NDArray[np.float64],
    sensitivities: NDArray[np.float64],
    daylight: CIEDaylight | None,
    offset: NDArray[np.float64],
    offset_sd: NDArray[np.float64],
    *,
    prior: float = LAMP_PRIOR,
) -> LampPosterior:
    """Each frame judged on its own, given the history's posterior of the scene-average offset (``offset`` ±
    ``offset_sd``): what :meth:`.scene.SceneModel.estimate` does for every new frame.

    A frame on its own adds nothing to the offset's posterior, so the integral over it is the Gaussian convolution of
    each hypothesis' mixture (isotropic, the offset's variance averaged over its two axes): ``N(u − a; c, s²)`` over
    ``a ~ N(â, σ_a²)`` is ``N(u − â; c, s² + σ_a²)``. One evaluation per frame instead of :func:`lamp_posterior`'s
    grid over the offset (a new frame's estimate took 40 ms with the grid, 1 ms without a lamp test).
    """
    dm = daylight or CIEDaylight()
    means = np.asarray(means, dtype=float)
    offset, offset_sd = np.asarray(offset, dtype=float), np.asarray(offset_sd, dtype=float)
    f = len(means)
    ok = np.all(np.isfinite(means), axis=1) & np.all(means > 0, axis=1)
    nd = np.full(f, np.nan)
    white = np.full((f, 3), np.nan)
    if ok.any():
        u_d, logw_d, u_l, logw_l = _population(sensitivities, dm)
        var_a = float(np.mean(offset_sd**2))
        u = log_chroma(means[ok]) - offset
        ld = _mixture_loglik(u, u_d, logw_d, math.sqrt(FRAME_SD**2 + var_a)) + math.log(1 - prior)
        ll = _mixture_loglik(u, u_l, logw_l, math.sqrt(FRAME_SD**2 + _LAMP_SD**2 + var_a)) + math.log(prior)
        nd[ok] = np.exp(ll - np.logaddexp(ld, ll))
        w = np.ones((int(ok.sum()), 3))
        w[:, 0], w[:, 2] = np.exp(u[:, 0]), np.exp(u[:, 1])
        white[ok] = w
    return LampPosterior(nd, white, offset, offset_sd)


def _frame_means(model, obs, theta: NDArray[np.float64], solver=None) -> NDArray[np.float64]:  # noqa: ANN001
    """Each frame's average over the model's patches (F × 3, the model's scale), a missing patch filled with the
    model's prediction under the frame's fitted daylight (so every frame averages the same scene). ``solver``: the
    model's :class:`~.solver.FrameSolver` over these patches (``model.solver`` of them, in their order) when the
    caller has one: only its operators ``G`` and ``b(θ)`` are read, which depend on nothing else (issue 29: a new
    frame's estimate built a second solver here, ~15 % of its time). A fit judges its history
    (:func:`history_lamps`) and applies the verdicts (:func:`apply_lamps`) with the same means: the first returns
    them and the second takes them (``means``), so they are computed once (~0.15 s of a 100k-frame refit)."""
    index = {p: i for i, p in enumerate(model.patches)}
    shared = [(j, index[p]) for j, p in enumerate(obs.patches) if p in index]
    oj, mi = [s[0] for s in shared], [s[1] for s in shared]
    if solver is None or solver.G.shape[0] != len(mi):
        solver = model.solver(mi)
    values = np.asarray(obs.values, dtype=float)
    out = np.empty((len(values), 3))
    for i in range(0, len(values), _MEANS_CHUNK):  # frame by frame: chunks bound the F × P × 3 temporaries
        y = values[i:i + _MEANS_CHUNK, oj] / model.noise["scale"]
        th = np.where(np.isfinite(theta[i:i + _MEANS_CHUNK]), theta[i:i + _MEANS_CHUNK], 0.0)
        b = solver._b(th[:, 0], th[:, 1], th[:, 2])
        pred = (b @ solver.G.reshape(-1, 3).T).reshape(len(b), -1, 3)  # Σ_k G[p, c, k] b[f, k]
        present = observed(y)
        filled = np.where(present[..., None], y, pred)
        part = filled.mean(axis=1)
        # a scene average needs most of the scene: frames showing fewer than half the model's patches have none
        part[(present.sum(axis=1) < 2) | (present.sum(axis=1) < 0.5 * len(model.patches))] = np.nan
        out[i:i + _MEANS_CHUNK] = part
    return out


_MEANS_CHUNK = 8192
"""Frames :func:`_frame_means` averages at once."""


class HistoryJudgement(NamedTuple):
    """What :func:`history_lamps` found of a history: each frame's ``non_daylight`` and the frames' scene averages it
    was judged on (:func:`_frame_means` at the history estimate's lights; :func:`apply_lamps` takes them again)."""

    non_daylight: NDArray[np.float64]
    means: NDArray[np.float64]


def history_lamps(model, obs) -> HistoryJudgement:  # noqa: ANN001
    """Judge every frame of the history ``obs`` a fitted :class:`~.scene.SceneModel` was fitted on: store the
    posterior of the scene-average offset in ``model.lamps`` and return each frame's ``non_daylight`` with the frame
    means it was judged on."""
    res = model.history_estimate[0] if model.history_estimate is not None else model.estimate(obs)[0]
    means = _frame_means(model, obs, np.asarray(res.info["theta"], dtype=float))
    unbalanced = _unbalanced_offset(model, means)
    camera_sd = float(model.camera.get("white_sd_log", 0.0) or 0.0)
    prior = unbalanced
    if prior is None:
        s = math.hypot(SCENE_OFFSET_SD, camera_sd)
        prior = (expected_scene_offset(model, obs), np.array([s, s]))
    lp = lamp_posterior(means, model.sensitivities, model.daylight_model(), camera_sd=camera_sd, offset_prior=prior)
    nd = lp.non_daylight
    # lamps only: no daylight frame pins the offset, the lamps' own colours are not the CIE populations' (filtered
    # lamps on the development scenes moved it 1.5 sd from the scene average's reading): the level's offset is kept
    offset, offset_sd = unbalanced if unbalanced is not None else (lp.offset, lp.offset_sd)
    model.lamps = {"offset": offset.tolist(), "offset_sd": offset_sd.tolist(), "prior": LAMP_PRIOR,
                   "daylight_frames": int(np.sum(np.isfinite(nd) & (nd < 0.5))), "frames": int(len(nd))}
    return HistoryJudgement(nd, means)


def expected_scene_offset(model, obs) -> NDArray[np.float64]:  # noqa: ANN001
    """Where the scene-average offset ``a`` of :func:`lamp_posterior` is expected for the history ``obs`` (log r/g,
    b/g): the mean measured surface's colour relative to the white under the daylight prior's mean reciprocal
    temperature (on the locus) through the model's camera, moved towards
    grey as far as the patches barely differ in colour (:func:`illumon.priors.scene_average.expected_offset`, the
    prior the calibration's and the level's scene-average readings use).

    The test once expected grey. Scenes of measured surfaces average warmer than grey (the development reflectance
    sets: +0.19…+0.25 log r/g, −0.19…−0.24 b/g through the development cameras under D55, 1.3 × that through a
    rendering matrix), so the offset was pulled towards blue and every frame read warmer than its light: direct sun
    then sat among the warm lamps (development ``imgsim`` clean history 3049: 17 of 26 frames above 0.5)."""
    index = {p: i for i, p in enumerate(model.patches)}
    cols = [j for j, p in enumerate(obs.patches) if p in index]
    values = np.asarray(obs.values, dtype=float)
    # only the frames the evidence reads are taken (the whole history's columns were copied and checked for the
    # 4 096 of a 100k-frame history, ~0.05 s a judgement); the same values
    v = values[evidence_frames(len(values))][:, cols]
    return _expected_offset(v, np.all(np.isfinite(v), axis=-1), model.sensitivities, model.daylight_model(),
                            model.reflectance_basis(), model.camera.get("primaries", "camera"))


def _expected_offset(values: NDArray[np.float64], present: NDArray[np.bool_], sensitivities: NDArray[np.float64],
                     dm: CIEDaylight, rb: ReflectanceBasis, primaries: str = "camera") -> NDArray[np.float64]:
    """:func:`illumon.priors.scene_average.expected_offset` under the daylight prior's mean light, of the scene
    average of ``values`` (F × P × 3, ``present`` F × P, in the output space ``primaries``) read from at most
    :data:`EVIDENCE_FRAMES` of its frames."""
    rows = evidence_frames(len(values))
    average = scene_average_evidence(values[rows], present[rows], primaries)
    light = dm.spectra(np.array([[dm.mired_mean, 0.0]]))
    return expected_offset(light, np.asarray(sensitivities, dtype=float), rb, average)[0]


EVIDENCE_FRAMES = 4096
"""Frames at most the scene-average evidence of :func:`expected_scene_offset` is read from (evenly spaced over a
longer history): only the patches' colour spread (a median over frames) moves the expectation, and over 100k frames
the evidence took 0.33 s of a refit (issue 29)."""


def evidence_frames(n: int) -> slice | NDArray[np.intp]:
    """The rows :func:`expected_scene_offset` reads of an ``n``-frame history: all, or :data:`EVIDENCE_FRAMES` evenly
    spaced (the same rows serve every scene-wide reading of a long history: the fit's output-space check too)."""
    return slice(None) if n <= EVIDENCE_FRAMES else np.linspace(0, n - 1, EVIDENCE_FRAMES).round().astype(np.intp)


def unbalanced_probability(model) -> float:  # noqa: ANN001
    """The probability the fit gave the history of being lit throughout by light its camera was not balanced for
    (:func:`illumon.model.level.common_level_posterior`'s ``unbalanced``, in ``model.noise`` when above one half); 0
    for a model without it."""
    return float(model.noise.get("unbalanced", 0.0) or 0.0)


def _unbalanced_offset(model, means: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
    """For a history lit only by light its camera was not balanced for (:mod:`.level`; ``model.noise["level"]``), the
    scene-average offset ``a`` that level implies — the frames' mean scene-average chroma minus the level, with the
    level's spread — else ``None`` (the default prior).

    The level is the mean white of the frames the scene was fitted on (``model.fit_frames``: the lamp rounds and the
    frames that bent the reflectances leave some out), so the mean is taken over those frames of ``means`` (the
    history's). Over every frame instead, the offset took the frames left out — a lamp-lit history's most extreme
    lamps, whose log chroma spreads by ~1 over its frames — as part of the scene's colour: development
    ``rawsim none+lamps`` (``python benchmarks/unmeasured.py --split dev --seeds 1 --cases none+lamps``) had two
    histories 11.4° and 8.6° off (median) where gray-world was 2.7° and 0.7°; the case's median 2.26 → 1.17°
    (gray-world 1.46°), its stated confidence 0.39 where 20 % of frames were within 1° → 0.41 where 41 % are."""
    if unbalanced_probability(model) <= 0.5 or "level" not in model.noise:
        return None
    ok = np.all(np.isfinite(means), axis=1) & np.all(means > 0, axis=1)
    fitted = getattr(model, "fit_frames", None)
    if fitted is not None and len(fitted) and int(np.max(fitted)) < len(means):
        # the level is the mean white of the frames the scene was fitted on: the offset is theirs too
        ok &= np.isin(np.arange(len(means)), fitted)
    if not ok.any():
        return None
    a = log_chroma(means[ok]).mean(axis=0) - np.asarray(model.noise["level"], dtype=float)
    sd = math.hypot(float(model.noise["level_sd"]), FRAME_SD / math.sqrt(int(ok.sum())))
    return a, np.array([sd, sd])


def log_chroma_confidence(white: NDArray[np.float64], var: NDArray[np.float64]) -> NDArray[np.float64]:
    """The probability that each camera white (F × 3) is within 1° of the truth, when its error is Gaussian in log r/g
    and log b/g with variances ``var`` (2,), independent.

    The angle is that of the RGB vectors, so the log-chromaticity errors go through the Jacobian of the white's unit
    vector (``J``, 3 × 2): near grey a log r/g error δ turns the white by ``√(2/9)·δ`` ≈ 0.47 δ radians, and the two
    log ratios turn it along directions 120° apart, so equal variances σ² give the angle the variances σ²/3 and σ²/9
    along its principal directions — not 2σ² in all, with which they were once equated (0.05–0.09 stated on lamp-lit
    histories where 37–50 % of frames were within 1°: ``benchmarks/lamps.py``, ``benchmarks/unmeasured.py``
    ``none+lamps``). The probability is that of that 2-D Gaussian inside the 1° circle, integrated over the direction:
    ``P = (1 / 2π√(λ₁λ₂)) ∫ (1 − exp(−ρ² q(θ) / 2)) / q(θ) dθ`` with ``q(θ) = cos²θ / λ₁ + sin²θ / λ₂``."""
    w = np.asarray(white, dtype=float)
    sd = np.sqrt(np.clip(np.asarray(var, dtype=float), 0.0, None))
    norm_w = np.linalg.norm(w, axis=1, keepdims=True)
    u = w / np.where(norm_w > 0, norm_w, 1.0)
    cols = []
    for c in (0, 2):  # d u / d log(w_c / w_g) = (I − u uᵀ) u_c e_c
        d = -u * u[:, c:c + 1] ** 2
        d[:, c] += u[:, c]
        cols.append(d)
    jac = np.stack(cols, axis=-1) * sd[None, None, :]  # F × 3 × 2
    lam = np.clip(np.linalg.eigvalsh(np.einsum("fci,fcj->fij", jac, jac)), 1e-30, None)  # F × 2, rad²
    theta = (np.arange(_CIRCLE_STEPS) + 0.5) * (2 * math.pi / _CIRCLE_STEPS)
    q = np.cos(theta)[None] ** 2 / lam[:, :1] + np.sin(theta)[None] ** 2 / lam[:, 1:]
    inner = -np.expm1(-0.5 * math.radians(1.0) ** 2 * q) / q
    return np.clip(inner.mean(axis=1) / np.sqrt(lam[:, 0] * lam[:, 1]), 0.0, 1.0)


_CIRCLE_STEPS = 256
"""Directions :func:`log_chroma_confidence` integrates over (the integrand is smooth and periodic: the midpoint rule
converges geometrically)."""


def _unbalanced_whites(model, lp: LampPosterior, result, extra: dict) -> bool:
    """A history lit only by lamps (:mod:`.level`): every frame's white is its scene average less the history's
    offset (the daylight fit cannot follow lights off its locus, and no daylight frame pins the scene), its
    ``non_daylight`` at least the history's probability of being lamp-lit. A measured sensor's frames are judged each
    on its own against that offset instead (its daylight whites are known): those more likely lamp-lit take the
    scene-average white, the others keep the daylight fit's and their own verdict. In place; ``True`` if it applied."""
    unbalanced = unbalanced_probability(model)
    if unbalanced <= 0.5 or "level" not in model.noise:
        return False
    lit = np.all(np.isfinite(lp.white), axis=1)
    camera = getattr(model, "camera", None) or {}
    if camera.get("calibration") == "measured" and camera.get("primaries", "camera") == "camera":
        # a measured sensor's daylight whites are known: with the offset the level gives, each frame is judged on its
        # own (a history lit by lamps most of the time keeps its daylight frames' verdicts and whites)
        lit &= lp.non_daylight > 0.5
    else:
        extra["non_daylight"] = np.maximum(extra["non_daylight"], unbalanced)
    _set_lamp_whites(result, extra, lit, lp.white, model.lamps["offset_sd"])
    return True


def _set_lamp_whites(result, extra: dict, mask: NDArray[np.bool_], white: NDArray[np.float64], offset_sd) -> None:
    """``white`` (and its gains) for the frames ``mask`` of ``result`` in place, with their ``confidence`` and 95 %
    gain intervals from the offset's spread ``offset_sd`` (log r/g, log b/g) and :data:`FRAME_SD`."""
    result.white[mask] = white[mask]
    result.gains[mask] = 1.0 / white[mask]
    var = np.asarray(offset_sd, dtype=float) ** 2 + FRAME_SD**2  # log r/g, log b/g
    extra["confidence"][mask] = log_chroma_confidence(result.white[mask], var)
    half = Z95 * math.sqrt(float(np.mean(var))) * result.gains[mask]
    result.info["gain_lo"][mask] = result.gains[mask] - half
    result.info["gain_hi"][mask] = result.gains[mask] + half


def apply_lamps(model, obs, result, extra: dict, solver=None,  # noqa: ANN001
                means: NDArray[np.float64] | None = None) -> None:
    """Add ``non_daylight`` to a scene model's per-frame estimate of ``obs`` (in place) and, for frames more likely
    lit by a lamp than by daylight in a history at least half of whose frames are daylight, replace the white and gains by the
    general illuminant's (:func:`.general.general_whites`), its ``confidence`` from the scene-average colour's posterior
    spread. CCT and Duv stay the nearest daylight's. Without ``model.lamps`` (a model saved before it) nothing is
    added. ``solver``: the estimate's own solver over ``obs``'s patches, reused for the frames' means
    (:func:`_frame_means`); ``means``: those means where the caller has them already (:func:`history_lamps` of the
    same model, ``obs`` and lights)."""
    lamps = getattr(model, "lamps", None)
    if not lamps:
        return
    lp, nd = _judged_frames(model, obs, np.asarray(result.info["theta"], dtype=float), solver, means)
    extra["non_daylight"] = nd
    if _unbalanced_whites(model, lp, result, extra):
        return
    lamp = (nd > 0.5) & np.all(np.isfinite(lp.white), axis=1)
    if not lamp.any() or (getattr(model, "camera", None) or {}).get("calibration") != "measured":
        # A camera nobody measured: its daylight whites are the prior's, so a lamp verdict is reported but not acted
        # on. On held-out rendered cameras (``python benchmarks/unmeasured.py --split score``, Hasselblad H2,
        # none+rendered) a third of a pure-daylight history's frames were judged lamp-lit and sent 33–36° off (1.3°
        # without); the lamp benchmarks' gains are on measured cameras.
        return
    if lamps.get("daylight_frames", 0) < max(MIN_DAYLIGHT_FRAMES, 0.5 * lamps.get("frames", 0)):
        # too few daylight frames to learn the scene from (a history judged mostly lamp-lit: then the judgement itself
        # rests on the scene-average prior, and so would the general white — gray-world's error); the frames are
        # reported, their whites stay the daylight fit's
        return
    # reflectances learned under daylight: fit the lamp's spectrum to them
    spectral = general_whites(model, obs, np.asarray(result.info["theta"], dtype=float), lamp)
    lamp = lamp & np.all(np.isfinite(spectral), axis=1)
    if not lamp.any():
        return
    _set_lamp_whites(result, extra, lamp, spectral, lamps["offset_sd"])


def _judged_frames(model, obs, theta: NDArray[np.float64], solver=None,  # noqa: ANN001
                   means: NDArray[np.float64] | None = None) -> tuple[LampPosterior, NDArray[np.float64]]:
    """Every frame of ``obs`` judged on its own against the history's scene-average offset (``model.lamps``,
    :func:`frame_lamp_posterior`) at the fitted lights ``theta``: the posterior and each frame's ``non_daylight`` (the
    prior where a frame has no scene average). ``means``: :func:`_frame_means` at ``theta`` where known."""
    lamps = model.lamps
    prior = float(lamps.get("prior", LAMP_PRIOR))
    if means is None:
        means = _frame_means(model, obs, theta, solver)
    lp = frame_lamp_posterior(means, model.sensitivities, model.daylight_model(), np.asarray(lamps["offset"]),
                              np.maximum(np.asarray(lamps["offset_sd"]), 0.01), prior=prior)
    return lp, np.where(np.isfinite(lp.non_daylight), lp.non_daylight, prior)


def frame_verdicts(model, obs) -> NDArray[np.float64] | None:  # noqa: ANN001
    """Each frame's ``non_daylight`` judged on its own against the scene-average offset of the history ``obs`` the
    model was fitted on — before :func:`apply_lamps` raises every frame of a history judged lamp-lit as a whole to the
    history's probability (a camera nobody measured, or rendered output: :func:`_unbalanced_whites`). Where the
    history is daylight the two agree. ``None`` without ``model.lamps`` or a history estimate."""
    if not getattr(model, "lamps", None) or model.history_estimate is None:
        return None
    return _judged_frames(model, obs, np.asarray(model.history_estimate[0].info["theta"], dtype=float))[1]


def non_daylight_column(obs, sensitivities: NDArray[np.float64], daylight: CIEDaylight | None = None,
                        primaries: str = "camera") -> NDArray[np.float64]:
    """``non_daylight`` of every frame of ``obs`` for a measured camera without a scene model (``illumon estimate``'s
    multi-frame retrieval): the frames' averages over the patches seen in every frame (all patches where fewer than
    two are), judged with the default priors (:func:`lamp_posterior`), the scene-average offset expected where
    :func:`expected_scene_offset` expects it (through the shipped reflectance prior; ``primaries``: the output space
    of ``obs``). 0 where a frame has no average."""
    v = np.asarray(obs.values, dtype=float)
    present = np.all(np.isfinite(v), axis=-1)
    common = present.all(axis=0)
    cols = common if common.sum() >= 2 else np.ones(v.shape[1], dtype=bool)
    with np.errstate(invalid="ignore"):
        means = np.nanmean(np.where(present[..., None], v, np.nan)[:, cols], axis=1)
    dm = daylight or CIEDaylight()
    css = np.asarray(sensitivities, dtype=float)
    expected = _expected_offset(v[:, cols], present[:, cols], css, dm, reflectance_basis(), primaries)
    nd = lamp_posterior(means, css, dm, offset_prior=(expected, np.full(2, SCENE_OFFSET_SD))).non_daylight
    return np.where(np.isfinite(nd), nd, 0.0)
