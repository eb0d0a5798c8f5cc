"""Request and response bodies, by resource. Floats reject NaN and infinity; lengths and signs are checked.

* :mod:`.common` — checked number and text types, the strict request base, times, error answers, multipart bodies;
* :mod:`.cameras` — registration, regions, a camera's public view;
* :mod:`.frames` — client-measured region means, a stored frame and its ingest answer;
* :mod:`.estimates` — estimates, the illuminant, white-balance gains;
* :mod:`.setup` — calibration images, region proposals, refit jobs.
"""

from .cameras import (
    AlertOut,
    CalibrationRef,
    CameraCreated,
    CameraIn,
    CameraOut,
    DeletedOut,
    ImageSizeIn,
    RegionIn,
    RegionsIn,
    ResponseIn,
    ResponseOut,
    SensitivitiesIn,
)
from .common import (
    CAMERA_APPLIED,
    ERROR_RESPONSES,
    MAX_LIST,
    MAX_SIDE,
    ErrorOut,
    HealthOut,
    IsoDateTime,
    multipart_body,
)
from .estimates import (
    AndroidGains,
    DngGains,
    EstimateOut,
    IlluminantOut,
    LibcameraGains,
    OnvifGains,
    OnvifVendorGains,
    SpectrumOut,
    V4l2Gains,
    WbGainsOut,
)
from .frames import FRAME_UPLOAD, FrameIngestOut, FrameOut, ObservationIn, RegionValues, RegistrationOut
from .setup import CalibrationOut, CalibrationPatchOut, JobOut, JobRef, ProposalOut, ProposalReasons, ProposalsOut

__all__ = [
    "SensitivitiesIn", "RegionIn", "ResponseIn", "CameraIn", "RegionsIn", "ObservationIn", "ErrorOut", "ERROR_RESPONSES",
    "FRAME_UPLOAD", "MAX_LIST", "multipart_body", "CAMERA_APPLIED", "EstimateOut", "SpectrumOut", "IlluminantOut", "JobRef",
    "HealthOut", "CameraOut", "CameraCreated", "FrameIngestOut", "FrameOut", "WbGainsOut", "JobOut", "CalibrationOut",
    "ProposalsOut", "DeletedOut",
    "IsoDateTime", "MAX_SIDE", "ImageSizeIn", "ResponseOut", "CalibrationRef", "AlertOut", "RegionValues",
    "RegistrationOut", "OnvifGains", "OnvifVendorGains", "LibcameraGains", "V4l2Gains", "DngGains", "AndroidGains",
    "CalibrationPatchOut", "ProposalReasons", "ProposalOut",
]
