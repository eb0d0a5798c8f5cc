"""Every database query of the service, one module per table or concern, and the public form of stored rows.

Routes, the status page, ingest, refits, jobs and upkeep read and write the database only through these functions
(the template's crud layer): a route stays thin, and the page and the JSON API cannot disagree. The functions take
a session (or an engine, for upkeep across transactions); the caller owns the transaction unless a function says it
commits.

* :mod:`.cameras` — cameras (by id or token), their views' regions, calibration images, deletion of a camera;
* :mod:`.frames` — frames by time and view, thumbnails, the history a refit reads, frames without an estimate;
* :mod:`.estimates` — estimates (nearest, by time, history) and their public form, a refit's replacement of them;
* :mod:`.jobs` — refit jobs and the warnings of a camera's latest refit;
* :mod:`.keys` — idempotency keys and login sessions;
* :mod:`.upkeep` — retention, backups, stored file paths of older versions.
"""

from .cameras import (
    add_calibration,
    calibrations,
    camera_by_token,
    camera_id_by_token_hash,
    camera_ids,
    camera_views,
    cameras,
    create_camera,
    delete_camera_rows,
    get_camera,
    has_calibration,
    models_for_update,
    set_view_regions,
    use_models,
    view_regions,
)
from .estimates import (
    WRITE_CHUNK,
    add_estimate,
    camera_history,
    drop_estimates,
    estimate_non_daylight,
    estimate_out,
    estimate_rows,
    estimate_spectrum,
    estimated_frame_ids,
    estimates_between,
    latest_estimate,
    nearest_estimate,
    recent_estimate_ids,
    replace_estimates,
)
from .frames import (
    add_frame,
    delete_frame,
    frame_count,
    frame_of,
    frame_out,
    frames_between,
    frames_not_read,
    history_chunks,
    last_thumbnail,
    latest_frame,
    mark_not_estimated,
    not_estimated_counts,
    recent_frames,
    thumbnail_frames,
    view_frames,
    view_size,
)
from .jobs import add_job, beat_jobs, claim_job, get_job, latest_job, refit_warnings, set_job, unfinished_jobs
from .keys import add_idempotency_key, add_login, delete_login, get_login, idempotency_key
from .upkeep import (
    delete_expired_logins,
    delete_frames_before,
    delete_jobs_finished_before,
    delete_keys_created_before,
    forget_missing_files,
    has_cameras,
    ping,
    relativize_paths,
    row_counts,
)

__all__ = [
    "add_calibration", "calibrations", "camera_by_token", "camera_id_by_token_hash", "camera_ids", "camera_views",
    "cameras", "create_camera", "delete_camera_rows", "get_camera", "has_calibration", "models_for_update",
    "set_view_regions", "use_models", "view_regions",
    "add_estimate", "camera_history", "drop_estimates", "estimate_non_daylight", "estimate_out",
    "estimate_rows", "estimate_spectrum", "estimated_frame_ids", "estimates_between", "latest_estimate",
    "nearest_estimate",
    "recent_estimate_ids", "replace_estimates", "WRITE_CHUNK",
    "add_frame", "delete_frame", "frame_count", "frame_of", "frame_out", "frames_between", "frames_not_read",
    "history_chunks", "last_thumbnail", "latest_frame", "mark_not_estimated", "not_estimated_counts", "recent_frames",
    "thumbnail_frames",
    "view_frames", "view_size",
    "add_job", "beat_jobs", "claim_job", "get_job", "latest_job", "refit_warnings", "set_job", "unfinished_jobs",
    "add_idempotency_key", "add_login", "delete_login", "get_login", "idempotency_key",
    "delete_expired_logins", "delete_frames_before", "delete_jobs_finished_before", "delete_keys_created_before",
    "forget_missing_files", "has_cameras", "ping", "relativize_paths", "row_counts",
]
