"""Calibration images: a ColorChecker or a grey card seen once by a camera nobody measured, so that its estimates rest
on a reference of known reflectance rather than on the prior from measured cameras alone.

A calibration image is measured like a frame — decoded, linearised with the camera's pipeline, and each patch's robust
mean taken by :func:`~.regions.region_means` (clipped pixels and outliers dropped) — but its "regions" are the
reference's patches:

* ``colorchecker``: the 24 patches of an X-Rite/Calibrite ColorChecker Classic, found by OpenCV contrib's Macbeth chart
  detector (``cv2.mcc``, chart type ``MCC24``; after Marrero Fernández et al. 2019, "Fast and robust multiple
  ColorChecker detection using deep convolutional neural networks", Image and Vision Computing 81), or, when the caller
  gives the chart's four corners, placed by the perspective transform of the 4 × 6 grid (:func:`grid_from_corners`).
  Each patch is sampled over a square of half the patch pitch around its centre (the chart's black gaps and the
  patch edges stay out). Ids ``chart:01`` … ``chart:24`` in the chart's order (dark skin … black), the ids of
  :func:`illumon.camera.colourchecker_references`.
* ``grey``: one rectangle of a grey card, id ``grey`` (:func:`illumon.camera.grey_card_reference`).

The refit then adds each stored calibration to the history as one extra frame holding only these reference patches
and passes their known reflectances to :func:`illumon.model.fit_scene_model` (see :mod:`.estimation`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from fastapi import HTTPException
from illumon.camera import ResponseCurve
from numpy.typing import NDArray
from sqlalchemy.orm import Session

from . import crud
from .decode import DecodedFrame, ImageError, decode_frame
from .regions import Region, RegionError, clipped_regions, region_means, response_for
from .settings import Settings
from .storage import Camera

__all__ = [
    "CalibrationError",
    "CHART_ROWS",
    "CHART_COLS",
    "chart_patch_ids",
    "grid_from_corners",
    "detect_colourchecker",
    "patch_regions",
    "measure_patches",
    "reference_box",
    "covered_regions",
    "CalibrationUpload",
    "store_calibration",
]

CHART_ROWS, CHART_COLS = 4, 6
"""The ColorChecker Classic's grid: 4 rows of 6 patches, patch 1 (dark skin) top-left, 19 (white) bottom-left."""

MAX_COORDINATE = 1e6
"""Largest corner coordinate accepted (pixels; beyond any image the service decodes)."""

SAMPLE_FRACTION = 0.5
"""Side of the sampled square, as a fraction of the patch pitch (centre-to-centre distance)."""


class CalibrationError(ValueError):
    """A calibration image that cannot be measured (no chart found, a region outside the image, everything clipped):
    the route answers 422 with the message."""


def chart_patch_ids(prefix: str = "chart:") -> list[str]:
    """``chart:01`` … ``chart:24``: the reference ids of the ColorChecker's patches in chart order."""
    return [f"{prefix}{i + 1:02d}" for i in range(CHART_ROWS * CHART_COLS)]


def grid_from_corners(corners: Sequence[Sequence[float]]) -> tuple[NDArray[np.float64], float]:
    """Patch centres (24 × 2, x y in pixels, chart order) and the patch pitch from the chart's four outer corners.

    ``corners`` are the corners of the 4 × 6 patch area in this order: next to patch 1 (dark skin, top-left when the
    chart is upright), next to patch 6 (bluish green), next to patch 24 (black), next to patch 19 (white). The centres
    are the images of ``(i + ½, j + ½)`` of a 6 × 4 grid under the perspective transform those corners define, so any
    rotation or tilt of the chart is handled.
    """
    bad = CalibrationError("corners: expected four [x, y] points in pixels (next to patches 1, 6, 24 and 19)")
    try:
        pts = np.asarray(corners, dtype=np.float64)
    except (TypeError, ValueError):
        raise bad from None
    if pts.shape != (4, 2) or not np.all(np.isfinite(pts)) or np.abs(pts).max() > MAX_COORDINATE:
        raise bad
    grid = np.array([[0, 0], [CHART_COLS, 0], [CHART_COLS, CHART_ROWS], [0, CHART_ROWS]], dtype=np.float32)
    try:
        h = cv2.getPerspectiveTransform(grid, pts.astype(np.float32))
    except cv2.error:
        h = np.zeros((3, 3))
    if not np.all(np.isfinite(h)) or abs(np.linalg.det(h)) < 1e-12:
        raise CalibrationError("corners: the four points do not span a quadrilateral")
    j, i = np.mgrid[0:CHART_ROWS, 0:CHART_COLS]
    cells = np.stack([i.ravel() + 0.5, j.ravel() + 0.5], axis=1)[None].astype(np.float64)
    centres = cv2.perspectiveTransform(cells, h)[0]
    step = np.concatenate([np.linalg.norm(np.diff(centres.reshape(CHART_ROWS, CHART_COLS, 2), axis=1), axis=2).ravel(),
                           np.linalg.norm(np.diff(centres.reshape(CHART_ROWS, CHART_COLS, 2), axis=0), axis=2).ravel()])
    return centres, float(np.min(step))


def detect_colourchecker(image: NDArray, full_scale: float) -> tuple[NDArray[np.float64], float]:
    """Patch centres (24 × 2, chart order) and pitch of the ColorChecker that OpenCV's ``cv2.mcc`` finds in ``image``
    (RGB, uint8 or uint16). Raises :class:`CalibrationError` when it finds none."""
    bgr = np.ascontiguousarray(image[:, :, ::-1])
    if bgr.dtype != np.uint8:
        bgr = np.round(bgr.astype(np.float64) * (255.0 / full_scale)).astype(np.uint8)
    detector = cv2.mcc.CCheckerDetector_create()
    detector.setColorChartType(cv2.mcc.MCC24)
    try:
        found = detector.process(bgr, 1)
    except cv2.error:  # e.g. an image too small to search
        found = False
    if not found:
        raise CalibrationError("no ColorChecker found in the image: give its four corners (form field 'corners', "
                               "[[x, y] × 4] next to patches 1, 6, 24 and 19), or a closer, evenly lit view")
    polygons = np.asarray(detector.getBestColorChecker().getColorCharts(), dtype=np.float64).reshape(-1, 4, 2)
    if polygons.shape[0] != CHART_ROWS * CHART_COLS:
        raise CalibrationError(f"the chart found has {polygons.shape[0]} patches, not {CHART_ROWS * CHART_COLS}")
    centres = polygons.mean(axis=1)
    sides = np.linalg.norm(np.diff(np.concatenate([polygons, polygons[:, :1]], axis=1), axis=1), axis=2)
    return centres, float(np.median(sides))


def patch_regions(ids: Sequence[str], centres: NDArray[np.float64], pitch: float, size: tuple[int, int]) -> list[Region]:
    """Square regions of :data:`SAMPLE_FRACTION` × ``pitch`` around each centre; :class:`CalibrationError` when one
    leaves the ``size`` = (width, height) image or is under 2 pixels."""
    side = int(SAMPLE_FRACTION * pitch)
    if side < 2:
        raise CalibrationError(f"the chart's patches are {pitch:.1f} pixels apart: too small to measure")
    w, h = size
    out = []
    for pid, (x, y) in zip(ids, centres, strict=True):
        x0, y0 = int(round(x - side / 2)), int(round(y - side / 2))
        if x0 < 0 or y0 < 0 or x0 + side > w or y0 + side > h:
            raise CalibrationError(f"patch {pid} ({x:.0f}, {y:.0f}) lies outside the {w}×{h} image")
        out.append(Region(pid, x0, y0, side, side))
    return out


def reference_box(regions: Sequence[Region], margin: float = 0.0) -> tuple[float, float, float, float]:
    """``(x0, y0, x1, y1)``: the bounding box of the reference's sampled regions, grown by ``margin`` pixels on each
    side (for a chart, about a patch pitch: the patches and the chart's surround around them)."""
    return (min(r.x for r in regions) - margin, min(r.y for r in regions) - margin,
            max(r.x + r.width for r in regions) + margin, max(r.y + r.height for r in regions) + margin)


def covered_regions(scene: Sequence[Region], box: tuple[float, float, float, float]) -> set[str]:
    """Ids of the camera's regions that overlap ``box``: the reference hides them in the calibration image, so their
    means there would be the reference's, not the scene's."""
    x0, y0, x1, y1 = box
    return {r.id for r in scene if r.x < x1 and r.x + r.width > x0 and r.y < y1 and r.y + r.height > y0}


def measure_patches(
    image: NDArray, regions: list[Region], response: ResponseCurve, *, clip_fraction: float, min_fraction: float
) -> tuple[list[dict], list[str]]:
    """Each patch's robust linear mean (:func:`~.regions.region_means`) and clipping flag
    (:func:`~.regions.clipped_regions`): ``([{"id", "r", "g", "b", "clipped"}], warnings)``; ``r, g, b`` are
    ``None`` for a patch mostly clipped or occluded. :class:`CalibrationError` when no patch is usable."""
    means = region_means(image, regions, response, clip_fraction=clip_fraction, min_fraction=min_fraction)
    clipped = clipped_regions(image, regions, response, clip_fraction)
    patches = []
    for r in regions:
        v = means[r.id]
        patches.append({"id": r.id, "r": None if v is None else v[0], "g": None if v is None else v[1],
                        "b": None if v is None else v[2], "clipped": r.id in clipped})
    usable = [p for p in patches if p["r"] is not None]
    if not usable:
        raise CalibrationError("every patch is clipped or unusable: expose the calibration image darker")
    warnings = []
    n_clip = sum(p["clipped"] for p in patches)
    if n_clip:
        warnings.append(f"{n_clip} of {len(patches)} patches have clipped pixels (those pixels are left out; a "
                        "patch mostly clipped has no value): a darker exposure measures them fully")
    if len(usable) < len(patches):
        warnings.append(f"{len(patches) - len(usable)} patches unusable (mostly clipped or occluded)")
    return patches, warnings


@dataclass(frozen=True)
class CalibrationUpload:
    """An uploaded calibration image as the form gave it (:func:`~.api.forms.read_calibration_form`)."""

    image: bytes | bytearray
    kind: str
    """``colorchecker`` or ``grey``."""
    corners: object | None = None
    """``colorchecker``: the patch area's four corners (checked by :func:`grid_from_corners`); found when ``None``."""
    region: Region | None = None
    """``grey``: the card's rectangle."""
    reflectance: float | None = None
    """``grey``: the card's reflectance."""
    applied_gains: list[float] | None = None
    exposure: float | None = None


def _reference(frame: DecodedFrame, upload: CalibrationUpload) -> tuple[list[Region], tuple[float, float, float, float]]:
    """The reference's patches in the image and the box they cover (:func:`reference_box`)."""
    if upload.kind == "grey":
        region, (w, h) = upload.region, frame.size
        if region.x + region.width > w or region.y + region.height > h:
            raise CalibrationError(f"region ({region.x},{region.y} {region.width}×{region.height}) lies "
                                   f"outside the {w}×{h} image")
        return [region], reference_box([region])
    centres, pitch = (grid_from_corners(upload.corners) if upload.corners is not None
                      else detect_colourchecker(frame.image, frame.full_scale))
    regions = patch_regions(chart_patch_ids(), centres, pitch, frame.size)
    return regions, reference_box(regions, margin=pitch)


def _measure(settings: Settings, cam: Camera, upload: CalibrationUpload) -> tuple[list[dict], dict, list[str]]:
    """The reference's patches (:func:`measure_patches`), the camera's own regions in the same image (those behind
    the reference left out) and the warnings."""
    frame = decode_frame(upload.image, [], max_pixels=settings.max_image_pixels, max_bytes=settings.max_decoded_bytes)
    response = response_for(cam.response, frame.full_scale)
    regions, box = _reference(frame, upload)
    patches, warnings = measure_patches(frame.image, regions, response, clip_fraction=settings.clip_fraction,
                                        min_fraction=settings.min_region_fraction)
    try:  # the camera's own regions in the same image: the reference's daylight comes from them
        scene = region_means(frame.image, [Region(**r) for r in cam.regions], response,
                             clip_fraction=settings.clip_fraction, min_fraction=settings.min_region_fraction)
    except RegionError:
        scene = {}
    hidden = covered_regions([Region(**r) for r in cam.regions], box) & set(scene)
    if hidden:  # behind the reference: their values here are the reference's
        scene.update(dict.fromkeys(hidden, None))
        warnings.append(f"{len(hidden)} of the camera's regions overlap the reference and are not used from "
                        f"this image ({', '.join(sorted(hidden)[:4])}{' …' if len(hidden) > 4 else ''})")
    if sum(v is not None for v in scene.values()) < 2:
        warnings.append("fewer than two of the camera's regions are usable in this image: a calibration "
                        "counts only in an image from the camera itself, showing its scene around the "
                        "reference; a refit leaves this one out")
    return patches, scene, warnings


def store_calibration(settings: Settings, session: Session, cam: Camera, upload: CalibrationUpload) -> dict:
    """Measure a calibration image, store it (committed) and build the 201 answer: the patches, how many clipped,
    how many of the camera's regions the image shows, and the warnings. 4xx for an image that cannot be decoded or
    a reference that cannot be found or measured."""
    try:
        patches, scene, warnings = _measure(settings, cam, upload)
    except ImageError as exc:
        raise HTTPException(exc.status, str(exc)) from None
    except CalibrationError as exc:
        raise HTTPException(422, str(exc)) from None
    row = crud.add_calibration(
        session, camera_id=cam.id, kind=upload.kind, reflectance=upload.reflectance,
        applied_gains=upload.applied_gains, exposure=upload.exposure, warnings=warnings,
        patches={p["id"]: None if p["r"] is None else [p["r"], p["g"], p["b"]] for p in patches},
        clipped=[p["id"] for p in patches if p["clipped"]], scene=scene)
    return {"calibration_id": row.id, "kind": upload.kind, "patches": patches, "clipped": len(row.clipped),
            "scene_regions": sum(v is not None for v in scene.values()), "warnings": warnings}
