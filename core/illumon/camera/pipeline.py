"""A camera's output pipeline: what happens to linear sensor values before they reach illumon.

An ordinary surveillance or panoramic camera does not deliver raw sensor values. Per frame it multiplies the linear
values by its current white-balance gains and an exposure (shutter × gain), mixes the channels with a fixed 3 × 3
colour matrix (sensor RGB → an output RGB such as sRGB's primaries), encodes with a tone curve and adds a black-level
pedestal::

    encoded = black + (white − black) · f( M · diag(g) · k · raw )

:class:`ResponseCurve` is ``f`` with the black and white levels (linear, sRGB, a gamma or a lookup table);
:class:`CameraPipeline` adds the matrix. illumon works in the camera's *output* linear space, ``M · raw``: every
estimate and gain it returns is for the values the camera software sees (a colour matrix only changes the effective
sensitivities, ``C Mᵀ``, see :mod:`illumon.camera.calibration`). :func:`undo_applied` divides out the per-frame gains
and exposure the camera reports, so a history stays consistent while the camera's own white balance changes.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import colour
import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..priors import colourchecker_reflectances
from ..registry import Registry
from ..spectra import GRID

__all__ = ["ENCODINGS", "ResponseCurve", "CameraPipeline", "undo_applied", "srgb_matrix"]

ENCODINGS = Registry.choices({
    "linear": "values proportional to the light",
    "srgb": "the sRGB encoding (IEC 61966-2-1)",
    "gamma": "a pure power law, exponent `gamma`",
    "table": "a measured curve, `table` of output values",
})
"""Tone curves a :class:`ResponseCurve` knows."""


@dataclass(frozen=True)
class ResponseCurve:
    """A camera's tone response: ``encoded = clip(black + (white − black) · f(linear))``.

    ``encoding`` is ``"linear"``, ``"srgb"`` (IEC 61966-2-1), ``"gamma"`` (power 1/``gamma``) or ``"table"``: ``table``
    holds the *linear* value (0…1, non-decreasing) of encoded values spaced evenly from the black to the white level
    (at least two entries; linear interpolation between them). Values are on a 0…``white_level`` scale with a
    ``black_level`` pedestal.
    """

    encoding: str = "linear"
    gamma: float = 2.2
    black_level: float = 0.0
    white_level: float = 255.0
    table: tuple[float, ...] = field(default=())

    def __post_init__(self) -> None:
        if self.encoding not in ENCODINGS:
            raise ValueError(f"unknown encoding {self.encoding!r}; use {', '.join(ENCODINGS)}")
        if not self.white_level > self.black_level:
            raise ValueError("white_level must exceed black_level")
        if self.encoding == "gamma" and not self.gamma > 0:
            raise ValueError("gamma must be positive")
        if self.encoding == "table":
            t = np.asarray(self.table, dtype=float)
            if t.ndim != 1 or t.size < 2 or not np.all(np.isfinite(t)):
                raise ValueError("a tone table needs at least two finite values")
            if np.any(np.diff(t) < 0) or t[0] < 0 or t[-1] <= 0:
                raise ValueError("a tone table must be non-decreasing, start at ≥ 0 and end above 0")
            object.__setattr__(self, "table", tuple(float(v) for v in t / t[-1]))

    def _codes(self) -> NDArray[np.float64]:
        return np.linspace(0.0, 1.0, len(self.table))

    def linearise(self, values: ArrayLike) -> NDArray[np.float64]:
        """Encoded values → linear light on a 0…1 scale."""
        v = (np.asarray(values, dtype=float) - self.black_level) / (self.white_level - self.black_level)
        v = np.clip(v, 0.0, None)
        if self.encoding == "srgb":
            return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)
        if self.encoding == "gamma":
            return v**self.gamma
        if self.encoding == "table":
            return np.interp(v, self._codes(), np.asarray(self.table))
        return v

    def encode(self, linear: ArrayLike) -> NDArray[np.float64]:
        """Linear light (0…1) → encoded values, clipped at the white level."""
        v = np.clip(np.asarray(linear, dtype=float), 0.0, 1.0)
        if self.encoding == "srgb":
            v = np.where(v <= 0.0031308, 12.92 * v, 1.055 * v ** (1 / 2.4) - 0.055)
        elif self.encoding == "gamma":
            v = v ** (1.0 / self.gamma)
        elif self.encoding == "table":
            v = np.interp(v, np.asarray(self.table), self._codes())
        return self.black_level + (self.white_level - self.black_level) * v


def _matrix(matrix: ArrayLike | None) -> NDArray[np.float64] | None:
    if matrix is None:
        return None
    m = np.asarray(matrix, dtype=float)
    if m.shape != (3, 3) or not np.all(np.isfinite(m)):
        raise ValueError("a colour matrix must be 3 × 3 finite numbers")
    if abs(np.linalg.det(m)) < 1e-9:
        raise ValueError("the colour matrix is singular")
    return m


@dataclass(frozen=True)
class CameraPipeline:
    """Tone curve and optional fixed 3 × 3 colour matrix of a camera (output = ``matrix @ raw`` per pixel).

    ``matrix`` is only needed to combine *measured raw* sensitivities with processed output; for an unmeasured camera
    the matrix is part of what a chart calibration estimates.
    """

    response: ResponseCurve = field(default_factory=ResponseCurve)
    matrix: tuple[tuple[float, ...], ...] | None = None

    def __post_init__(self) -> None:
        m = _matrix(self.matrix)
        if m is not None:
            object.__setattr__(self, "matrix", tuple(tuple(float(v) for v in row) for row in m))

    def output_sensitivities(self, raw_sensitivities: ArrayLike) -> NDArray[np.float64]:
        """Effective sensitivities (61 × 3) of the output channels: ``C Mᵀ`` (``C`` itself without a matrix)."""
        c = np.asarray(raw_sensitivities, dtype=float)
        return c if self.matrix is None else c @ np.asarray(self.matrix).T

    def linearise(self, values: ArrayLike) -> NDArray[np.float64]:
        """Encoded output values → linear output values (0…1)."""
        return self.response.linearise(values)


def _positive(name: str, value: ArrayLike, n: int) -> NDArray[np.float64]:
    v = np.asarray(value, dtype=float)
    if v.shape[-1:] != (n,) and not (n == 1 and v.ndim <= 1):
        raise ValueError(f"{name} must have {n} value(s) per frame")
    if not np.all(np.isfinite(v)) or np.any(v <= 0):
        raise ValueError(f"{name} must be positive finite numbers")
    return v


def undo_applied(
    linear_rgb: ArrayLike,
    applied_gains: ArrayLike | Sequence[float] | None = None,
    exposure: ArrayLike | float | None = None,
    matrix: ArrayLike | None = None,
) -> NDArray[np.float64]:
    """Divide the camera's own per-frame white-balance gains and exposure out of linear output values.

    Parameters
    ----------
    linear_rgb
        Linear output values (…, 3): one frame's region means (P × 3) or a history (F × P × 3).
    applied_gains
        The r, g, b multipliers the camera applied to linear values in this frame (3,) or per frame (F × 3).
    exposure
        Relative exposure the camera applied (scalar or (F,)).
    matrix
        The camera's fixed colour matrix, when known: the gains act *before* it, so they are undone as
        ``M diag(1/g) M⁻¹``. Without it they are undone channel by channel.

    Returns
    -------
    ndarray
        Values as if the camera had applied unit gains and unit exposure.
    """
    y = np.array(linear_rgb, dtype=float)
    if exposure is not None:
        k = _positive("exposure", exposure, 1)
        y = y / (k[..., None, None] if k.ndim == 1 and y.ndim == 3 else k)
    if applied_gains is not None:
        g = _positive("applied_gains", applied_gains, 3)
        m = _matrix(matrix)
        if m is None:
            y = y / (g[:, None, :] if g.ndim == 2 and y.ndim == 3 else g)
        else:
            mi = np.linalg.inv(m)
            if g.ndim == 2:
                ops = np.einsum("ij,fj,jk->fik", m, 1.0 / g, mi)
                y = np.einsum("fik,fpk->fpi", ops, y) if y.ndim == 3 else np.einsum("fik,fk->fi", ops, y)
            else:
                y = y @ (m @ np.diag(1.0 / g) @ mi).T
    return y


def srgb_matrix(raw_sensitivities: ArrayLike) -> NDArray[np.float64]:
    """The 3 × 3 colour matrix a camera maker would fit for these sensitivities: linear raw → linear sRGB, least
    squares on the 24 ColorChecker patches under CIE D65 (colour-science's data), scaled so D65 white maps to grey
    of the same green. For simulating processed output and as a starting point when raw sensitivities are measured."""
    c = np.asarray(raw_sensitivities, dtype=float)
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"].copy().align(GRID).values
    d65 = colour.SDS_ILLUMINANTS["D65"].copy().align(GRID).values
    _, cc = colourchecker_reflectances()
    raw = (cc * d65) @ c
    xyz = (cc * d65) @ cmfs
    to_xyz = np.linalg.lstsq(raw, xyz, rcond=None)[0].T  # xyz ≈ M raw
    m = np.asarray(colour.models.RGB_COLOURSPACE_sRGB.matrix_XYZ_to_RGB) @ to_xyz
    white = m @ (d65 @ c)
    return m * (d65 @ c)[1] / white[1]
