"""Leave-one-camera-out evaluation of the single-chart estimators on simulated charts.

A chart is rendered with a measured camera under a measured daylight spectrum (linear model,
:func:`illumon.camera.render`), Gaussian noise with standard deviation ``noise × max`` is added, and each method
estimates the sensitivities with priors rebuilt *without* the camera under test (and without another measurement of
the same model: the two Nikon D50 files are one camera). The metric is
:func:`~illumon.sensitivity.common.rmse_per_channel`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..camera import render
from ..priors import CameraPrior, build_camera_prior
from .common import SensitivityResult, rmse_per_channel

__all__ = ["simulate_chart", "camera_model", "camera_manufacturer", "leave_one_out", "LooResult"]


def simulate_chart(
    sensitivities: ArrayLike,
    illuminant: ArrayLike,
    reflectances: ArrayLike,
    noise: float = 0.005,
    rng: np.random.Generator | int | None = None,
) -> NDArray[np.float64]:
    """Chart values (P × 3) scaled so the brightest is 1, with Gaussian noise of σ = ``noise`` (clipped at
    0)."""
    rng = np.random.default_rng(rng)
    x = render(sensitivities, illuminant, reflectances)
    x = x / x.max()
    return np.clip(x + noise * rng.standard_normal(x.shape), 0.0, None)


def camera_model(name: str) -> str:
    """Camera model of a measurement file stem (``Nikon_D50_ssf`` and ``Nikon_D50`` are one model)."""
    return name.removesuffix("_ssf")


def camera_manufacturer(name: str) -> str:
    """Manufacturer of a measurement file stem (``Canon_50D`` → ``Canon``, ``Point_Grey_…`` → ``Point Grey``): the
    group held out together by the leave-one-manufacturer-out protocol (a prior that has seen a Canon 60D should not
    score a Canon 50D)."""
    for prefix in ("Point_Grey", "Phase_One"):
        if name.startswith(prefix):
            return prefix.replace("_", " ")
    return name.split("_")[0]


@dataclass
class LooResult:
    """Per-camera mean RMSE (cameras × 3) of one method, with the camera names."""

    method: str
    cameras: list[str]
    rmse: NDArray[np.float64]
    seconds: float = 0.0
    extra: dict = field(default_factory=dict)

    @property
    def mean(self) -> NDArray[np.float64]:
        """Mean R, G, B RMSE over cameras."""
        return self.rmse.mean(axis=0)

    @property
    def overall(self) -> float:
        """Mean RMSE over cameras and channels."""
        return float(self.rmse.mean())

    @property
    def worst(self) -> tuple[str, float]:
        """Camera with the largest channel-mean RMSE and that RMSE."""
        i = int(np.argmax(self.rmse.mean(axis=1)))
        return self.cameras[i], float(self.rmse[i].mean())


def leave_one_out(
    method: Callable[..., SensitivityResult],
    cameras: Mapping[str, NDArray[np.float64]],
    illuminants: ArrayLike,
    reflectances: ArrayLike,
    *,
    test_cameras: Sequence[str] | None = None,
    noise: float | Sequence[float] = 0.005,
    seed: int = 0,
    name: str = "",
    prior_builder: Callable[[list[NDArray[np.float64]]], CameraPrior] = build_camera_prior,
    chart_maker: Callable[..., dict] | None = None,
    group: Callable[[str], str] = camera_model,
    chart_renderer: Callable[..., NDArray[np.float64]] = simulate_chart,
    **kwargs: object,
) -> LooResult:
    """Leave-one-group-out RMSE of ``method`` over ``test_cameras`` × ``illuminants`` (by default one camera model
    at a time; ``group=camera_manufacturer`` holds out every camera of the manufacturer).

    Parameters
    ----------
    method
        ``method(chart_rgb, chart_reflectances, camera_prior=..., **kwargs) -> SensitivityResult``.
    cameras
        All measured cameras by name (each 61 × 3).
    illuminants
        Daylight spectra (F × 61) under which each test camera's chart is rendered.
    reflectances
        Chart reflectances (P × 61).
    test_cameras
        Cameras to hold out in turn (default: all).
    noise
        Relative noise level, or one per illuminant (cycled).
    chart_maker
        Optional ``chart_maker(camera, illuminant, rng) -> dict`` of extra keyword arguments per chart (Han et al.'s
        fluorescent chart values).
    group
        Name → group; the prior is rebuilt without every camera of the test camera's group.
    chart_renderer
        ``chart_renderer(camera, illuminant, reflectances, noise, rng) -> (P × 3)`` chart values
        (default :func:`simulate_chart`; the benchmark also renders through an independent raw pipeline).
    """
    import time

    t0 = time.perf_counter()
    names = list(test_cameras or cameras)
    e = np.atleast_2d(np.asarray(illuminants, dtype=float))
    r = np.asarray(reflectances, dtype=float)
    levels = np.atleast_1d(np.asarray(noise, dtype=float))
    rng = np.random.default_rng(seed)
    out = np.empty((len(names), 3))
    for i, cam in enumerate(names):
        prior = prior_builder([c for n, c in cameras.items() if group(n) != group(cam)])
        errs = []
        for f, spd in enumerate(e):
            x = chart_renderer(cameras[cam], spd, r, float(levels[f % levels.size]), rng)
            extra = chart_maker(cameras[cam], spd, rng) if chart_maker is not None else {}
            res = method(x, r, camera_prior=prior, **extra, **kwargs)
            errs.append(rmse_per_channel(res.sensitivities, cameras[cam]))
        out[i] = np.mean(errs, axis=0)
    return LooResult(name or getattr(method, "__name__", "method"), names, out, time.perf_counter() - t0)
