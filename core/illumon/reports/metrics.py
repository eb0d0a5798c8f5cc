"""The measures the daylight report scores spectral fits with: the goodness-of-fit coefficient, the relative RMSE
after the best scale, and a percentile that tolerates empty rows.

References
----------
.. [Romero1997] Romero et al., JOSA A 1997: the GFC.
.. [HernandezAndres2001] Hernández-Andrés et al., JOSA A 2001: GFC ≥ 0.999 colorimetrically accurate, ≥ 0.9999 a good
   spectral fit.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["gfc", "rel_rmse", "scaled", "q"]


def gfc(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """Goodness-of-fit coefficient |⟨a, b⟩| / (‖a‖‖b‖) along the last axis.

    References
    ----------
    .. [Romero1997] Romero et al., JOSA A 1997.
    """
    return np.abs((a * b).sum(-1)) / (np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1))


def rel_rmse(fit: NDArray[np.float64], e: NDArray[np.float64]) -> NDArray[np.float64]:
    """RMSE of ``fit`` after its best scale onto ``e``, relative to the mean level of ``e``."""
    s = (fit * e).sum(-1, keepdims=True) / (fit * fit).sum(-1, keepdims=True)
    return np.sqrt(np.mean((s * fit - e) ** 2, axis=-1)) / e.mean(-1)


def scaled(fit: NDArray[np.float64], e: NDArray[np.float64]) -> NDArray[np.float64]:
    """``fit`` times its best least-squares scale onto ``e`` (along the last axis)."""
    return fit * ((fit * e).sum(-1, keepdims=True) / (fit * fit).sum(-1, keepdims=True))


def q(a: NDArray[np.float64] | list, p: float = 50) -> float:
    """The ``p``-th percentile of ``a``, NaN when ``a`` is empty (a report row with nothing to summarise)."""
    a = np.asarray(a, dtype=float)
    return float(np.percentile(a, p)) if a.size else float("nan")
