"""Experiment (issue 28, branch ``diag-imgsim``; reverted in the next commit): the fluorescence ratio of development
histories under variants of :func:`illumon.diagnosis.spectral.generic_fluorescence_gains`.

Run: ``python benchmarks/fluorescence_variants.py OUT.json none,fluorescence illumon,rawsim,imgsim 10 VARIANT`` with
``VARIANT`` ``stokes`` (emission colours restricted to light at λ ≥ band centre − 0, 10, 20, 30 nm), ``channel``
(three almost unpenalised reflectance-like columns in the null: ``diag`` per channel, ``sens`` shaped like the
channels' sensitivities) or ``local`` (:data:`~illumon.diagnosis.spectral.LOCAL_REFLECTANCE_SD` 0.05, 0.1, 0.2).
"""

from __future__ import annotations

import json
import sys
import warnings
from concurrent.futures import ProcessPoolExecutor

import diagnose as bd
import numpy as np
import rawsim
from illumon.diagnosis import spectral, stages
from illumon.diagnosis.noise import dark_level_set, history_dark_level
from scipy.stats import chi2

VARIANTS = {"stokes": ("stokes_nm", [None, 0.0, 10.0, 20.0, 30.0]), "channel": ("channel_free", [None, "diag", "sens"]),
            "local": ("local_sd", [0.05, 0.1, 0.2])}


def one(sim: str, effect: str, i: int, variant: str) -> dict:
    """The best patch, its ratio to the runner-up and band under each setting of ``variant``."""
    warnings.filterwarnings("ignore")
    obs, css, _, patch, _, _, seed = bd.history(sim, effect, i, rawsim.DEV_CAMERAS, bd.DEV_SEED0, "dev")
    key, values = VARIANTS[variant]
    out: dict = {"sim": sim, "effect": effect, "seed": seed, "patch": patch, "res": {}}
    with dark_level_set(history_dark_level(obs.values, None)):
        base = stages.refined_spectral_base(obs, css)
        for v in values:
            fg, fband, share = spectral.generic_fluorescence_gains(base, **{key: v})
            p = int(np.argmax(fg))
            scale = max(float(np.sort(fg)[-2]), float(chi2.median(3)))
            out["res"][str(v)] = {"p": p, "ratio": float(fg[p] / scale), "band": int(fband[p]),
                                  "share": share[p].round(3).tolist()}
    return out


def main() -> int:
    out, effects, sims = sys.argv[1], sys.argv[2].split(","), sys.argv[3].split(",")
    seeds, variant = int(sys.argv[4]), sys.argv[5]
    jobs = [(s, e, i, variant) for s in sims for e in effects for i in range(seeds)]
    with ProcessPoolExecutor(2) as ex:
        rows = list(ex.map(one, *zip(*jobs, strict=True)))
    with open(out, "w") as fh:
        json.dump(rows, fh, indent=1)
    for r in rows:
        print(r["sim"][:4], r["effect"][:5], r["seed"], r["patch"], " | ".join(
            f"{k}: p{v['p']} {v['ratio']:.2f} b{v['band']}" for k, v in r["res"].items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
