"""Lamp-lit frames in daylight histories of measured cameras, judged with lamps mixed with 1, 3 or 7 daylights.

The effect simulator's ``off_locus_illuminant`` histories (:func:`illumon.simulation.effects.hide_effect`: daylight
mixed 35–80 % with a fluorescent, LED or high-pressure lamp in some frames) on its *development* cameras, fitted with
the camera's measured sensitivities; printed per history: the share of lamp-lit and of daylight frames with
``non_daylight`` ≥ 0.5 and the median camera-white error of each, then their means. The figures behind
:data:`illumon.model.lamps.MIX_DAYLIGHTS`.

``python tools/lamp_mixing.py --mix-daylights 3``
"""

from __future__ import annotations

import argparse
import warnings

import numpy as np
from illumon.camera import angular_error_deg
from illumon.model import fit_scene_model
from illumon.model import lamps as lamp_module
from illumon.simulation import datasets
from illumon.simulation.effects import DEV_CAMERAS, hide_effect


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mix-daylights", type=int, default=lamp_module.MIX_DAYLIGHTS)
    args = ap.parse_args(argv)
    lamp_module.MIX_DAYLIGHTS = args.mix_daylights
    for fn in (lamp_module._population, lamp_module.lamp_population):  # the defaults were bound at import
        fn.__defaults__ = (*fn.__defaults__[:-1], args.mix_daylights)
    rows = []
    for i, camera in enumerate(DEV_CAMERAS):
        h = hide_effect("off_locus_illuminant", camera, 20000 + i)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            model = fit_scene_model(h.observations, datasets.load_camera(camera))
        res, extra = model.history_estimate
        lamp = np.array(h.parameters["frames"])
        nd = extra["non_daylight"]
        day = np.setdiff1d(np.arange(len(nd)), lamp)
        err = angular_error_deg(res.white, h.history.true_white)
        rows.append((np.mean(nd[lamp] >= 0.5), np.mean(nd[day] >= 0.5), np.median(err[lamp]), np.median(err[day])))
        print(f"{camera:16} lamp-lit flagged {rows[-1][0]:.2f}  daylight flagged {rows[-1][1]:.2f}  "
              f"error lamp-lit {rows[-1][2]:.2f}°  daylight {rows[-1][3]:.2f}°")
    m = np.mean(rows, axis=0)
    print(f"mean (mix daylights {args.mix_daylights}): lamp-lit flagged {m[0]:.2f}, daylight flagged {m[1]:.2f}, "
          f"error lamp-lit {m[2]:.2f}°, daylight {m[3]:.2f}°")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
