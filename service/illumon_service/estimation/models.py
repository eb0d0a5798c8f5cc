"""Scene-model files of a camera's views and the loaded models: where a refit writes a new version, which file a view
uses, and the cache of loaded models and their per-frame solvers (:class:`illumon.model.FrameSolver`)."""

from __future__ import annotations

import os
import threading
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from illumon import model as scene_model
from illumon.model import FrameSolver

__all__ = ["model_path", "model_available", "view_model_key", "versioned_model_path", "current_model",
           "load_model", "known_indices", "solver_for", "save_model", "forget_model", "remove_old_models",
           "MODEL_CACHE_SIZE"]


def model_path(data_dir: Path | str, camera_id: int, view: str | None = None) -> Path:
    """Where the fitted scene model of a camera (of one of its views, a PTZ preset) is stored."""
    suffix = "" if view is None else f"-view-{view}"
    return Path(data_dir) / "models" / f"camera-{camera_id}{suffix}.json"


def model_available(data_dir: Path | str, camera_id: int, view: str | None = None) -> bool:
    """Whether per-frame estimation is possible for the camera (a scene model has been fitted)."""
    return model_path(data_dir, camera_id, view).is_file()


def view_model_key(view: str | None) -> str:
    """Key of a view in :attr:`..storage.Camera.models` (``default`` for a fixed camera's one view)."""
    return "default" if view is None else f"v-{view}"


def versioned_model_path(data_dir: Path | str, camera_id: int, view: str | None, version: str) -> Path:
    """Where a refit writes a new scene model: ``models/camera-<id>[-view-<view>].<version>.json`` (a new file per
    refit; the camera row says which one is in use)."""
    legacy = model_path(data_dir, camera_id, view)
    return legacy.with_name(f"{legacy.stem}.{version}.json")


def current_model(data_dir: Path | str, models: dict | None, camera_id: int, view: str | None = None
                  ) -> tuple[Path, str] | None:
    """``(file, version)`` of the scene model a camera's view uses (:attr:`..storage.Camera.models`), or the
    unversioned file of an older version (version ``legacy``) when the camera row names none; ``None`` before the
    first refit."""
    entry = (models or {}).get(view_model_key(view))
    if entry and entry.get("file"):
        return Path(data_dir) / "models" / str(entry["file"]), str(entry.get("version") or "")
    legacy = model_path(data_dir, camera_id, view)
    return (legacy, "legacy") if legacy.is_file() else None



@dataclass
class _Loaded:
    """A scene model file as loaded (its modification time) and the per-frame solvers built for it, one per list of
    the camera's regions (building one costs more than solving a frame)."""

    mtime: int
    model: scene_model.SceneModel
    solvers: dict[tuple[int, ...], FrameSolver] = field(default_factory=dict)


MODEL_CACHE_SIZE = 256
"""Scene models kept loaded (oldest dropped first)."""
_MODEL_CACHE: dict[str, _Loaded] = {}
_CACHE_LOCK = threading.Lock()


def load_model(path: Path) -> _Loaded:
    """The scene model at ``path``, loaded once per file version (the per-frame solve is then ~1 ms)."""
    mtime = path.stat().st_mtime_ns
    key = str(path)
    with _CACHE_LOCK:
        hit = _MODEL_CACHE.get(key)
        if hit is not None and hit.mtime == mtime:
            return hit
    loaded = _Loaded(mtime, scene_model.SceneModel.load(path))
    with _CACHE_LOCK:
        if len(_MODEL_CACHE) >= MODEL_CACHE_SIZE:  # versioned files: old versions are never asked for again
            _MODEL_CACHE.pop(next(iter(_MODEL_CACHE)))
        _MODEL_CACHE[key] = loaded
    return loaded


def forget_model(path: Path) -> None:
    """Drop the loaded model of ``path`` from the cache (a refit just wrote it)."""
    _MODEL_CACHE.pop(str(path), None)


def known_indices(model: scene_model.SceneModel, region_ids: Sequence[str]) -> tuple[int, ...]:
    """The model's indices of the regions it knows, in the regions' order (as ``SceneModel.estimate`` matches them)."""
    index = {p: i for i, p in enumerate(model.patches)}
    return tuple(index[p] for p in region_ids if p in index)


def solver_for(loaded: _Loaded, region_ids: list[str]) -> FrameSolver:
    """The model's per-frame solver over the regions it knows, built once per loaded model and region list and kept
    in the service's cache. ``SceneModel.estimate`` matches patches in this same order."""
    mi = known_indices(loaded.model, region_ids)
    with _CACHE_LOCK:
        hit = loaded.solvers.get(mi)
    if hit is None:
        hit = loaded.model.solver(list(mi))
        with _CACHE_LOCK:
            loaded.solvers[mi] = hit
    return hit



def save_model(fitted: scene_model.SceneModel, path: Path) -> None:
    """Write a fitted scene model atomically: readers see the old or the new model, never half of one."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(f".{os.getpid()}.{threading.get_ident()}.tmp")
    fitted.save(tmp)
    os.replace(tmp, path)



def remove_old_models(data_dir: Path | str, camera_id: int, new_models: dict[str | None, Path], started: float) -> None:
    """Delete the model files of the refitted views other than the new ones, older than this refit (``started``, a
    Unix time; an older version's unversioned file too; a newer refit running elsewhere keeps its file)."""
    for v, keep in new_models.items():
        legacy = model_path(data_dir, camera_id, v)
        for p in [legacy, *legacy.parent.glob(f"{legacy.stem}.*.json")]:
            try:
                if p != keep and p.is_file() and p.stat().st_mtime < started:
                    p.unlink()
            except FileNotFoundError:
                pass
