"""The light's temperature read by a camera nobody measured, after a reference (issue 26: a D65 light box read as
17 400 K). Simulated histories of development cameras (``tools/camera_mired_spread.py``): frame 0 under CIE D65
shows the reference, a Granada run follows."""

from __future__ import annotations

import numpy as np
import pytest
from illumon.simulation import datasets

pytestmark = pytest.mark.skipif(datasets.shared_data_dir() is None, reason="measured data (../shared/data) not found")

CAMERAS = ("Nikon_D3X", "Nikon_D700", "Point_Grey_Grasshopper2_14S5C")


@pytest.mark.parametrize(("primaries", "case"), [("srgb", "chart"), ("srgb", "grey"), ("camera", "chart")])
def test_cct_after_a_reference(primaries, case):
    import camera_mired_spread as tool

    rows = [tool.run(cam, case, 1000 + i, primaries) for i, cam in enumerate(CAMERAS)]
    err = np.concatenate([r["err"] for r in rows])
    rms = float(np.sqrt(np.mean(err**2)))
    # a constant D65 reading on the same frames (the Granada runs span ~4000–20000 K) is far off: the test can fail
    constant = np.concatenate([tool.D65_MIRED - r["true_mired"] for r in rows])
    assert np.sqrt(np.mean(constant**2)) > 20.0
    assert rms < 16.0, rms
    for r in rows:
        assert 5900.0 < r["cct"][0] < 7200.0, r["cct"][0]  # the D65 light-box frame
        assert r["cct_lo"][0] < 6504.0 < r["cct_hi"][0]  # its stated 95 % interval holds the truth
