"""Sensor RGB of a camera nobody measured, no reference: the channel scales read from the scene's average colour are
read again at each refit's light until they hold, and the temperature's interval holds how the scene's colour splits
between the scales and the light (:func:`illumon.camera.calibration.calibrate_scene_model`)."""

from __future__ import annotations

import functools

import numpy as np
import pytest


def _run(case: str, camera: str, seed: int, *, once: bool = False) -> dict:
    """``benchmarks/unmeasured.py``'s three-frame history (``rawsim``, development camera and seed), fitted without
    sensitivities; ``once``: the scales read once (the calibration before they were read until they held)."""
    import illumon.model.fit as fit_module
    import unmeasured
    from illumon.camera import calibration

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(unmeasured, "FRAMES", 3)
        if once:
            mp.setattr(fit_module, "calibrate_scene_model",
                       functools.partial(calibration.calibrate_scene_model, max_iterations=1))
        return unmeasured.run_case("rawsim", camera, case, seed)


@pytest.mark.parametrize(("camera", "seed", "before", "after"), [
    ("Nikon_D3X", 7400, 1.67, 0.68),
    ("Nikon_Z6_ssf", 8200, 1.94, 1.03),
])
def test_scales_read_until_they_hold(shared_data, camera, seed, before, after):
    """Lamps near the daylight locus over pale surfaces (``raw+lamps``), judged daylight: read once, the scales took
    the scene's colour at the first fit's light, the refit's light then relaxed towards the daylight prior's and left
    the white short (median 1.67° and 1.94°); read until they hold, 0.68° and 1.03°. The light's temperature moved
    by 69 and 61 MK⁻¹ doing so, and the 95 % CCT intervals, widened by that move, hold every frame's lamp (none of
    them without the widening)."""
    now, once = _run("raw+lamps", camera, seed), _run("raw+lamps", camera, seed, once=True)
    assert np.median(once["err"]) == pytest.approx(before, abs=0.1)
    assert np.median(now["err"]) == pytest.approx(after, abs=0.1)
    assert now["split_mired"] < -40.0  # bluer: the scales took the lamps' warmth
    assert all(now["cct_in_95"])
    # the move is in the stated spread (read back from the 95 % interval, as if symmetric)
    assert np.all(np.asarray(now["mired_sd"]) > 0.9 * abs(now["split_mired"]))


def test_a_history_judged_lamp_lit_reads_its_scales_once(shared_data):
    """Lamps far from the locus (``raw+lamps``, Nikon D200, seed 7 000: judged lit by lamps throughout): the scene's
    colour is the lamps', the scales are read once, and the white is the one a single reading gave."""
    now, once = _run("raw+lamps", "Nikon_D200", 7000), _run("raw+lamps", "Nikon_D200", 7000, once=True)
    np.testing.assert_allclose(now["err"], once["err"], atol=1e-9)
    assert all(now["cct_in_95"])
