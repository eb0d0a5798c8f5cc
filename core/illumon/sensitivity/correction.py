"""Colour correction with known sensitivities: per-channel gains (Han et al. 2012) and a 3 × 3 transfer (Huynh).

* :func:`channel_gains_Han2012` — eq. (20): a scene point seen by camera ``c`` under light ``l`` is predicted
for
  camera ``c̄`` under light ``l̄`` by multiplying each channel by ``∫ c̄ l̄ / ∫ c l``.
* :func:`transfer_matrix_Huynh2014` — Huynh & Robles-Kelly §IV: camera colours ``I`` (m × 3) map to the CIE
1931
  2° observer as ``I Q† Q̂ diag(σ)``, with ``Q`` the camera's and ``Q̂`` the observer's (normalised) curves.

References
----------
.. [Han2012] Han et al., CVPR 2012: eq. 20.
.. [Huynh2014] Huynh & Robles-Kelly, ICPR 2014: §IV.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..camera import camera_white
from ..daylight import CMFS

__all__ = ["channel_gains_Han2012", "correct_Han2012", "transfer_matrix_Huynh2014", "to_cie1931_Huynh2014"]


def channel_gains_Han2012(
    sensitivities: ArrayLike,
    illuminant: ArrayLike,
    target_sensitivities: ArrayLike | None = None,
    target_illuminant: ArrayLike | None = None,
) -> NDArray[np.float64]:
    """Per-channel gains (3,) of Han et al. eq. (20) from (camera, light) to (target camera, target light).

    References
    ----------
    .. [Han2012] Han et al., CVPR 2012: eq. 20.
    """
    c_dst = sensitivities if target_sensitivities is None else target_sensitivities
    l_dst = illuminant if target_illuminant is None else target_illuminant
    return camera_white(c_dst, l_dst) / camera_white(sensitivities, illuminant)


def correct_Han2012(rgb: ArrayLike, gains: ArrayLike) -> NDArray[np.float64]:
    """Apply eq. (20) gains to camera values (…, 3)."""
    return np.asarray(rgb, dtype=float) * np.asarray(gains, dtype=float)


def transfer_matrix_Huynh2014(
    sensitivities: ArrayLike, target: ArrayLike | None = None, sigma: ArrayLike | None = None
) -> NDArray[np.float64]:
    """The 3 × 3 matrix ``Q† Q̂ diag(σ)`` taking camera colours to the target curves (default: CIE 1931 2°).

    ``Q`` and ``Q̂`` are each normalised to a maximum of 1 (the paper normalises both); ``σ`` (default ones)
    rescales the output channels.

    References
    ----------
    .. [Huynh2014] Huynh & Robles-Kelly, ICPR 2014: §IV.
    """
    q = np.asarray(sensitivities, dtype=float)
    q = q / q.max()
    qh = CMFS if target is None else np.asarray(target, dtype=float)
    qh = qh / qh.max()
    m = np.linalg.pinv(q) @ qh
    s = np.ones(3) if sigma is None else np.asarray(sigma, dtype=float)
    return m * s[None, :]


def to_cie1931_Huynh2014(rgb: ArrayLike, sensitivities: ArrayLike) -> NDArray[np.float64]:
    """Camera colours (m × 3) → CIE 1931 XYZ up to the normalisation of the curves (Huynh §IV)."""
    return np.asarray(rgb, dtype=float) @ transfer_matrix_Huynh2014(sensitivities)
