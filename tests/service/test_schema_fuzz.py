"""Schemathesis against the service's own OpenAPI schema (issue 9): no 5xx, no response that breaks the schema.

Runs in-process on the ASGI app (admin token, a registered camera with frames so that ``/v1/cameras/1/...`` exists).
Examples per operation are bounded (``ILLUMON_FUZZ_EXAMPLES``, 25 by default; ``ILLUMON_LONG_TESTS=1`` → 300).

Marked ``serial``: ``make test`` runs it in one process after the parallel run. Under pytest-xdist schemathesis's
per-operation cases collapse into one item that exercised only the first operation (9 calls where a plain run makes
~1 300 over 18 operations), and said "1 passed".
"""

from __future__ import annotations

import os
import tempfile

import numpy as np
import pytest

schemathesis = pytest.importorskip("schemathesis")
pytestmark = pytest.mark.serial

from fastapi.testclient import TestClient  # noqa: E402
from hypothesis import HealthCheck, settings  # noqa: E402
from illumon_service.app import create_app  # noqa: E402
from schemathesis.specs.openapi.checks import positive_data_acceptance  # noqa: E402
from svc_helpers import ADMIN, camera_body, encode_png, grid_regions, make_settings  # noqa: E402

EXAMPLES = int(os.environ.get("ILLUMON_FUZZ_EXAMPLES", "300" if os.environ.get("ILLUMON_LONG_TESTS") else "25"))
_TMP = tempfile.TemporaryDirectory(prefix="illumon-fuzz-")


def _app():
    app = create_app(make_settings(_TMP.name, jobs_inline=True))
    wl = np.arange(400, 701, 5)
    css = np.column_stack([np.exp(-0.5 * ((wl - c) / 30) ** 2) for c in (600, 540, 460)])
    with TestClient(app) as c:
        r = c.post("/v1/cameras", json=camera_body(css, grid_regions()), headers={"Authorization": f"Bearer {ADMIN}"})
        cam, token = r.json()["id"], r.json()["token"]
        img = encode_png(np.full((240, 320, 3), (120, 110, 100), np.uint8))
        for i in range(3):
            c.post(f"/v1/cameras/{cam}/frames", files={"image": ("f.png", img, "image/png")},
                   data={"taken_at": f"2025-06-01T1{i}:00:00Z"}, headers={"Authorization": f"Bearer {token}"})
    return app


APP = _app()
schema = schemathesis.openapi.from_asgi("/openapi.json", APP).include(path_regex=r"^/(v1/|healthz|metrics)")


@pytest.fixture(autouse=True)
def _one_process():
    """A pytest-xdist worker would run one operation and call it passed."""
    if os.environ.get("PYTEST_XDIST_WORKER"):
        pytest.skip("schemathesis's operations do not distribute under pytest-xdist: run this file in one process "
                    "(make test does)")


@schema.parametrize()
@settings(max_examples=EXAMPLES, deadline=None, suppress_health_check=list(HealthCheck), database=None)
def test_openapi_fuzz(case):
    """Every default check except ``positive_data_acceptance``: the service also validates what JSON Schema cannot say
    (equal lengths, coverage of 400–700 nm, regions inside the image, a decodable image), and answers those 422."""
    case.call_and_validate(headers={"Authorization": f"Bearer {ADMIN}"}, excluded_checks=[positive_data_acceptance])
