"""Service settings from the environment (prefix ``ILLUMON_``) and the command line."""

from __future__ import annotations

from functools import cached_property
from pathlib import Path
from typing import Literal

from illumon.registry import Registry
from illumon.retrieval import METHODS
from pydantic import Field, field_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

__all__ = ["Settings", "REFIT_METHODS"]

REFIT_METHODS: Registry[object] = METHODS.with_first(
    "model", None, "fit the scene model and estimate every frame with it, linear in the history")
"""What a refit estimates with (``ILLUMON_REFIT_METHOD``): the scene model, or a multi-frame retrieval method of
:data:`illumon.retrieval.METHODS`."""
RefitMethod = REFIT_METHODS.literal()


class Settings(BaseSettings):
    """Configuration of the illumon service.

    Every field can be set as ``ILLUMON_<FIELD>`` in the environment, e.g. ``ILLUMON_DATABASE_URL``.
    """

    model_config = SettingsConfigDict(env_prefix="ILLUMON_", extra="ignore")

    data_dir: Path = Path("./var")
    """Folder for the SQLite database, the generated admin token, fitted models and kept images."""
    database_url: str | None = None
    """SQLAlchemy URL (e.g. ``postgresql+psycopg://user:pw@host/db``); SQLite under ``data_dir`` when unset."""
    admin_token: str | None = None
    """Admin bearer token; generated and stored in ``data_dir/admin_token`` (mode 0600) when unset."""
    max_upload_bytes: int = Field(default=32 * 1024 * 1024, gt=0)
    """Largest accepted image upload."""
    max_image_pixels: int = Field(default=50_000_000, gt=0)
    """Largest accepted decoded image (width × height)."""
    keep_images: bool = False
    """Keep uploaded images under ``data_dir/images``."""
    refit_max_frames: int = Field(default=100_000, ge=2)
    """A refit re-estimates at most this many of the most recent frames."""
    refit_method: RefitMethod = "model"
    """``model``: fit the scene model and estimate every frame with it (linear in the history); or a multi-frame
    retrieval method (``joint`` grows faster than linearly: set ``refit_max_frames`` to a few hundred with it)."""
    refit_fit_frames: int = Field(default=300, ge=2)
    """Frames the scene model's reflectances are fitted on (spread over the history's illuminant range)."""
    refit_every_hours: float = Field(default=0.0, ge=0.0)
    """Refit every camera every N hours inside the service (0 = off; use ``illumon refit`` from cron instead)."""
    pending_max_frames: int = Field(default=64, ge=0, le=10_000)
    """Original images kept per camera view while it has no regions, measured once they are confirmed (the oldest
    beyond this number are dropped; their frames stay stored without values). 0: keep none."""
    pending_max_bytes: int = Field(default=512 * 1024 * 1024, gt=0)
    """…and at most this many bytes of them per camera view (oldest dropped first)."""
    max_decoded_bytes: int = Field(default=64 * 1024 * 1024, gt=0)
    """Largest decoded image in bytes (width × height × channels × bytes per sample, as the header states, checked
    before decoding): bounds the memory one upload can take, for 16-bit images too."""
    job_stale_seconds: float = Field(default=60.0, gt=0)
    """A ``running`` refit job whose process has given no sign of life (heartbeat, every few seconds) for this long
    was orphaned by a crash: it is marked failed and run again."""
    jobs_inline: bool = False
    """Run refit jobs synchronously inside the request (tests); otherwise in a background thread."""
    min_region_fraction: float = Field(default=0.5, gt=0.0, le=1.0)
    """A region is missing in a frame when fewer than this fraction of its pixels are usable."""
    clip_fraction: float = Field(default=0.98, gt=0.0, le=1.0)
    """Pixels at or above this fraction of the white level in any channel count as clipped."""
    metrics_dir: Path | None = None
    """Folder where each worker process publishes its metrics so that ``/metrics`` sums all of them; ``illumon serve
    --workers N`` sets it to ``data_dir/metrics`` (one process: unset, metrics stay in memory)."""
    jpeg_max_reduction: int = 1
    """Decode 8-bit JPEG frames at up to 1/N of their size (libjpeg DCT scaling) when every region keeps at least 32
    decoded pixels per side; region edges that cut decoded pixels are weighted by coverage. 1 (default): always full
    size. 2 decodes 1920×1080 ~35 % faster; the region means then average codes over 2×2 pixels before linearising:
    ~0.04 % (median) from the full decode's on smooth regions, ~0.2 % (p95 0.6 %) on finely textured ones, and the
    white up to ~0.06° (docs/service.md, *Ingest speed*)."""

    retain_days: float = Field(default=0.0, ge=0.0)
    """Delete frames (with their estimates, thumbnails and kept images) taken more than this many days ago, and
    finished refit jobs as old; checked every hour by the service (and by ``illumon prune``). 0 (default): keep
    everything."""
    metrics: Literal["public", "admin", "off"] = "public"
    """``/metrics``: ``public`` (default: anyone who reaches the port; the figures hold counts and timings, no camera
    data, names or tokens), ``admin`` (``Authorization: Bearer`` with the admin token) or ``off`` (404)."""

    @field_validator("jpeg_max_reduction")
    @classmethod
    def _reduction(cls, value: int) -> int:
        """1, 2, 4 or 8: the factors libjpeg can decode at."""
        if value not in (1, 2, 4, 8):
            raise ValueError("jpeg_max_reduction must be 1, 2, 4 or 8")
        return value

    @cached_property
    def resolved_database_url(self) -> str:
        """The database URL in use: the configured one, else ``sqlite:///<data_dir>/illumon.sqlite3``."""
        if self.database_url:
            return self.database_url
        return f"sqlite:///{(Path(self.data_dir) / 'illumon.sqlite3').resolve()}"
