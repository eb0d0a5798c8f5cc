"""The refit's tone-response check before and after issue 29, interleaved in one run: the whole diagnosis with the
bilinear fit's Gram sums as three-operand einsums (before) against the tone-curve test alone with the Gram sums as
matrix products (after, :func:`illumon_service.estimation.check_response`), on the frames the check samples from
2k-frame histories (``benchmarks/refit.py``'s: 16 patches, 10 % missing; 48 frames) and on tone-encoded versions of
them (values ^ (1/2.2): the check must warn). Prints the seconds of each side, their ratio and both verdicts, and
writes ``benchmarks/results/response_check.json``.

    nice python benchmarks/response_check.py [--histories 3] [--rounds 3]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
import warnings
from pathlib import Path

import numpy as np
from illumon.diagnosis import bilinear as bl
from illumon.diagnosis.fit import NONE_MARGIN, diagnose
from illumon.simulation import simulate_history
from illumon_service.estimation import RESPONSE_CHECK_FRAMES, build_observations, check_response, seen_patches
from refit import N_PATCHES, spectra

RESULTS = Path(__file__).with_name("results")


def _einsum_cols(w: np.ndarray, u: np.ndarray) -> np.ndarray:
    return np.einsum("fj,fa,fb->jab", w, u, u)


def _einsum_rows(w: np.ndarray, v: np.ndarray) -> np.ndarray:
    return np.einsum("fj,aj,bj->fab", w, v, v)


def before(frames: list, ids: list[str], css: np.ndarray) -> tuple[bool, float]:
    """The check as it was: the whole diagnosis (einsum Gram sums) on the same sample; (warns, γ)."""
    new_cols, new_rows = bl._gram_cols, bl._gram_rows
    bl._gram_cols, bl._gram_rows = _einsum_cols, _einsum_rows
    try:
        obs = build_observations(frames, ids)
        keep = np.flatnonzero(obs.present.sum(axis=1) >= 3)
        keep = keep[np.round(np.linspace(0, keep.size - 1, min(RESPONSE_CHECK_FRAMES, keep.size))).astype(int)]
        d = diagnose(seen_patches(obs.subset(keep)), css, reestimate=False)
    finally:
        bl._gram_cols, bl._gram_rows = new_cols, new_rows
    tone = next(c for c in d.candidates if c.effect == "nonlinear_response")
    warns = tone.score < -NONE_MARGIN["nonlinear_response"]
    return bool(warns), float(tone.parameters["gamma"]) if warns else float("nan")


def after(frames: list, ids: list[str], css: np.ndarray) -> tuple[bool, float]:
    """The check as it is; (warns, γ)."""
    out = check_response(frames, ids, css, "linear")
    return bool(out["warnings"]), float(out["gamma"]) if out["gamma"] is not None else float("nan")


def main() -> None:
    """Time both sides interleaved; print and write the results."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--histories", type=int, default=3)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--frames", type=int, default=2000)
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    css, day, refl, provenance = spectra()
    ids = [f"p{j:02d}" for j in range(N_PATCHES)]
    cases = []
    for seed in range(1, args.histories + 1):
        idx = (np.arange(args.frames) * 7 + seed * 131) % len(day)
        vals = simulate_history(css, day[idx], refl, rng=seed, missing_fraction=0.1).observations.values
        for label, v in (("linear", vals), ("gamma 2.2", np.clip(vals, 0, None) ** (1 / 2.2))):
            frames = [(str(f), f"2025-06-01T00:{f % 60:02d}:00+00:00",
                       {p: (None if not np.isfinite(v[f, j, 0]) else v[f, j].tolist()) for j, p in enumerate(ids)})
                      for f in range(args.frames)]
            cases.append((f"seed {seed} {label}", frames))
    after(cases[0][1], ids, css)  # imports (SciPy) outside the timing
    rows = []
    print(f"data: {provenance}; {args.frames} frames × {N_PATCHES} patches, {RESPONSE_CHECK_FRAMES} checked; "
          f"load {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs")
    print(f"{'history':<18} {'before s':>9} {'after s':>8} {'before÷after':>13} {'verdict before':>15} {'verdict after':>14}")
    for name, frames in cases:
        tb, ta = [], []
        for r in range(args.rounds):
            for side in ((before, tb), (after, ta)) if r % 2 == 0 else ((after, ta), (before, tb)):
                t = time.perf_counter()
                verdict = side[0](frames, ids, css)
                side[1].append(time.perf_counter() - t)
                if side[0] is before:
                    vb = verdict
                else:
                    va = verdict
        b, a = statistics.median(tb), statistics.median(ta)
        rows.append({"history": name, "before_s": b, "after_s": a, "ratio": b / a, "before": vb, "after": va})
        fmt = lambda v: f"warn γ {v[1]:.2f}" if v[0] else "ok"  # noqa: E731
        print(f"{name:<18} {b:9.2f} {a:8.2f} {b / a:13.1f} {fmt(vb):>15} {fmt(va):>14}", flush=True)
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "response_check.json").write_text(json.dumps({"data": provenance, "rows": rows}, indent=1) + "\n")
    print(f"wrote {RESULTS / 'response_check.json'}")


if __name__ == "__main__":
    main()
