"""Fast CIE D-series weights ``(1, M1, M2)`` of ``(reciprocal CCT, offset from the daylight locus)`` from a tabulated
Planckian locus, for the per-frame solver's inner loop (CIE 015:2018 §4.1 for the D-series; Ohno 2013 for Duv)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from ..daylight import MIRED_RANGE, daylight_locus_duv
from ..daylight.ohno2013 import planck_locus

__all__ = ["WeightTable", "weight_table"]


class WeightTable:
    """Tabulated Planckian locus, its normal and the daylight-locus Duv on a fine reciprocal-temperature grid, so the
    CIE D weights ``(1, M1, M2)`` of ``(mired, δ)`` cost a handful of array operations."""

    def __init__(self) -> None:
        p = planck_locus()
        self.m0 = float(MIRED_RANGE[0] - 5.0)
        self.dm = 0.25
        m = np.arange(self.m0, MIRED_RANGE[1] + 10.0, self.dm)
        cols = [np.interp(m, p.mired, p.uv[:, 0]), np.interp(m, p.mired, p.uv[:, 1])]
        cols += [np.interp(m, p.mired, p.normal[:, 0]), np.interp(m, p.mired, p.normal[:, 1])]
        cols.append(daylight_locus_duv(1e6 / m))
        self.table = np.stack(cols, axis=1)
        self.n = m.size

    def lookup(self, mired: NDArray[np.float64]) -> NDArray[np.float64]:
        """Interpolated table rows (…, 5): u0, v0, nu, nv, locus Duv."""
        x = (mired - self.m0) / self.dm
        i = np.minimum(np.maximum(x.astype(np.int64), 0), self.n - 2)
        t = (x - i)[..., None]
        return self.table[i] * (1.0 - t) + self.table[i + 1] * t

    def weights(self, mired: NDArray[np.float64], delta: NDArray[np.float64]) -> NDArray[np.float64]:
        """CIE D basis weights (…, 3) = (1, M1, M2) for reciprocal CCT ``mired`` and offset ``delta`` from the locus."""
        r = self.lookup(mired)
        duv = r[..., 4] + delta
        u = r[..., 0] + duv * r[..., 2]
        v = r[..., 1] + duv * r[..., 3]
        den = 2 * u - 8 * v + 4
        x, y = 3 * u / den, 2 * v / den
        m = 0.0241 + 0.2562 * x - 0.7341 * y
        out = np.empty(m.shape + (3,))
        out[..., 0] = 1.0
        out[..., 1] = (-1.3515 - 1.7703 * x + 5.9114 * y) / m
        out[..., 2] = (0.0300 - 31.4424 * x + 30.0717 * y) / m
        return out


_TABLE: WeightTable | None = None


def weight_table() -> WeightTable:
    global _TABLE
    if _TABLE is None:
        _TABLE = WeightTable()
    return _TABLE


