"""What makes ``confidence`` say what it means for a camera nobody measured, per calibration and output space.

``confidence`` is the probability a frame's camera white is within 1° of the truth (:mod:`illumon.model.intervals`):
``1 − exp(−ρ² / tr)`` with ``tr`` the angular variance of the white — the Laplace posterior of the frame's light,
scaled by ``a²``, plus ``2 · (s² + k² g²)``, ``s`` the camera model's own log-gain spread and ``g`` what the
reference frames' veiling glare leaves uncertain in this history's white (``camera_glare_log``,
:func:`illumon.camera.calibration._glare_white_sd`; 0 without a reference)
(:data:`illumon.camera.calibration.STATED_WHITE_SPREAD` holds ``(a, s, k)``). This tool reads the rows that
``benchmarks/unmeasured.py`` writes (every frame's error, ``confidence``, the ``a`` and total spread it was stated
with, and ``g``), backs out each frame's Laplace part and, per regime (calibration × primaries), chooses ``(a, s, k)``:
among the triples with which the mean stated confidence equals the fraction of frames within 1°, the one with the
largest Bernoulli likelihood of which frames were (which rewards stating less where the glare moved the white more).
Reference frames (frame 0 of a reference case: confidence from
:data:`~illumon.camera.calibration.REFERENCE_WHITE_SD_DEG` and the glare a dark or light neutral reads beside a mid
grey) keep what they stated.

Regimes and the cases they are chosen on (the raw ``none`` case, not ``none+matrix``: a camera with no reference
cannot tell a fixed matrix from none, and the outside checks' raw sets are the raw case):

=================  ==========================  ==============================
regime             chosen on                   reported beside
=================  ==========================  ==============================
camera / grey      ``grey``
camera / chart     ``chart+matrix``
camera / none      ``none``                    ``none+matrix``
srgb / grey        ``grey+rendered``, ``grey+awb``
srgb / chart       ``chart+rendered``, ``chart+awb``
srgb / none        ``none+rendered``, ``none+awb``
=================  ==========================  ==============================

After the regimes it prints what the rows' own statements say against what happened, per source file (glared
histories marked) and case (:func:`as_stated`): a regime is calibrated over its pooled cases and sources, and this
table shows where the pooled choice parts — histories with and without veiling glare, or scenes of one kind against
another (``pale``, ``room``, the lamp-lit cases), which no regime is chosen on.

Run on the **development** split only (``python benchmarks/unmeasured.py --split dev --seeds 2 --out dev.json``,
then ``python tools/confidence_calibration.py dev.json``); the score split checks the result.

Short histories (:data:`illumon.camera.calibration.SHORT_HISTORY_WHITE_SPREAD`: ``unmeasured.py --frames 3`` or
``--frames 6``) read their noise level from fewer values than parameters, which inflates the Laplace part:
``--scales-from 0.01`` lets ``a`` go below the 30-frame regimes' 0.5. Rows that carry each frame's stated
temperature spread (``mired_sd``) and the key it was stated with (``mired_key``,
:func:`illumon.camera.calibration.camera_mired_key`: a chart read, read as rendered, or refused) also print, per key,
the RMS reciprocal-temperature error, the RMS stated spread, the fraction the 95 % intervals hold (as if symmetric),
and the spread to add in quadrature for z-scores of RMS 1 (``add z``:
:data:`~illumon.camera.calibration.SHORT_HISTORY_MIRED_SD`) or for 95 % held (``add95``). Per key, not per regime: a
regime's chart cases hold charts read and refused, whose spreads differ.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
from scipy.optimize import brentq

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "core")]

from illumon.model.intervals import MODEL_ERROR, Z95, confidence_variance, within_one_degree  # noqa: E402

REGIMES = {
    ("camera", "grey"): ("grey",),
    ("camera", "chart"): ("chart+matrix",),
    ("camera", "none"): ("none",),
    ("srgb", "grey"): ("grey+rendered", "grey+awb"),
    ("srgb", "chart"): ("chart+rendered", "chart+awb"),
    ("srgb", "none"): ("none+rendered", "none+awb"),
}


def _frames(rows: list[dict], cases: tuple[str, ...]
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(tr without the camera's spread, error, is-a-reference-frame, the history's glare spread ``g``, the
    confidence each frame stated) over the frames of ``cases``."""
    base, err, ref, glare, given = [], [], [], [], []
    for r in rows:
        if r["case"] not in cases:
            continue
        c = np.clip(np.asarray(r["confidence"], dtype=float), 1e-12, 1 - 1e-12)
        s, a = float(r["camera_log_gain"]), float(r.get("laplace_scale", 1.0))
        tr = (confidence_variance(c) - 2 * (MODEL_ERROR["log_gain"] ** 2 + s**2)) / a**2
        is_ref = np.zeros(len(c), dtype=bool)
        is_ref[0] = not r["case"].startswith("none")
        base.append(np.clip(tr, 0.0, None))
        err.append(np.asarray(r["err"], dtype=float))
        ref.append(is_ref)
        glare.append(np.full(len(c), float(r.get("camera_glare_log", 0.0))))
        given.append(c)
    return (np.concatenate(base), np.concatenate(err), np.concatenate(ref), np.concatenate(glare),
            np.concatenate(given))


def stated(a: float, s: float, base: np.ndarray, ref: np.ndarray, ref_conf: np.ndarray | float, k: float = 0.0,
           glare: np.ndarray | float = 0.0) -> np.ndarray:
    """Every frame's stated confidence with the Laplace part scaled by ``a``, the camera spread ``s`` and ``k`` times
    the history's glare spread ``glare`` (reference frames keep theirs, ``ref_conf``)."""
    tr = a**2 * base + 2 * (MODEL_ERROR["log_gain"] ** 2 + s**2 + (k * np.asarray(glare)) ** 2)
    return np.where(ref, ref_conf, within_one_degree(tr))


def mean_confidence(s: float, base: np.ndarray, ref: np.ndarray, ref_conf: np.ndarray | float, a: float = 1.0,
                    k: float = 0.0, glare: np.ndarray | float = 0.0) -> float:
    """Mean stated confidence over the frames (see :func:`stated`)."""
    return float(np.mean(stated(a, s, base, ref, ref_conf, k, glare)))


SCALES = np.round(np.exp(np.linspace(np.log(0.5), np.log(12.0), 41)), 3)
"""Laplace scales tried (the Laplace posterior understates what the model leaves out by a factor)."""


def scales_from(least: float) -> np.ndarray:
    """:data:`SCALES`, continued below 0.5 at the same ratio down to ``least`` (a short history's noise level is
    read from fewer values than it has parameters, which inflates the Laplace part: ``--scales-from``)."""
    ratio = SCALES[1] / SCALES[0]
    n = max(int(np.floor(np.log(0.5 / least) / np.log(ratio) + 1e-9)), 0)
    below = np.round(0.5 / ratio ** np.arange(n, 0, -1), 3)
    return np.concatenate([below, SCALES])


def extra_for_unit_z(err: np.ndarray, sd: np.ndarray) -> float:
    """The standard deviation to add in quadrature to ``sd`` so that the errors' z-scores have RMS 1 (0 if they
    do)."""
    if np.mean(err**2 / sd**2) <= 1.0:
        return 0.0
    return float(brentq(lambda x: np.mean(err**2 / (sd**2 + x**2)) - 1.0, 0.0, 1000.0))


def extra_for_coverage(err: np.ndarray, sd: np.ndarray, coverage: float = 0.95) -> float:
    """The least standard deviation to add in quadrature to ``sd`` with which ``coverage`` of the errors lie within
    their 95 % intervals (``Z95`` standard deviations; 0 if they do)."""
    def held(x: float) -> float:
        return float(np.mean(np.abs(err) <= Z95 * np.sqrt(sd**2 + x**2)))
    if held(0.0) >= coverage:
        return 0.0
    lo, hi = 0.0, 1000.0
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if held(mid) >= coverage else (mid, hi)
    return hi


def mired_extra(rows: list[dict]) -> tuple[float, float, float, float, float] | None:
    """Over ``rows``' frames with a CCT interval: the RMS reciprocal-temperature error, the RMS stated spread
    (``mired_sd``, from each 95 % interval's width), the fraction the intervals hold, and the spread to add in
    quadrature for z-scores of RMS 1 and for 95 % held (MK⁻¹); ``None`` for rows written without ``mired_sd``."""
    err, sd = [], []
    for r in rows:
        if "mired_sd" in r:
            err.append(np.asarray(r["mired_err"], dtype=float))
            sd.append(np.asarray(r["mired_sd"], dtype=float))
    if not err:
        return None
    e, s = np.concatenate(err), np.concatenate(sd)
    ok = np.isfinite(e) & np.isfinite(s) & (s > 0)
    e, s = e[ok], s[ok]
    return (float(np.sqrt(np.mean(e**2))), float(np.sqrt(np.mean(s**2))), float(np.mean(np.abs(e) <= Z95 * s)),
            extra_for_unit_z(e, s), extra_for_coverage(e, s))

GLARE_FACTORS = np.round(np.linspace(0.0, 1.5, 16), 2)
"""Factors ``k`` tried on the reference frames' glare spread (``camera_glare_log``: what the reference fit's offset
prior leaves uncertain in the white; 0 where there is no reference)."""


def solve(rows: list[dict], cases: tuple[str, ...], scales: np.ndarray = SCALES) -> dict:
    """The Laplace scale ``a``, camera spread ``s`` (log units) and glare factor ``k`` for ``cases``' frames: among the
    triples with which the mean stated confidence equals the fraction within 1° (calibration in the large), the one
    with the largest Bernoulli likelihood of which frames were within (a proper score: it rewards telling good frames
    from bad, and so the histories whose reference frame had more glare)."""
    base, err, ref, glare, ref_conf = _frames(rows, cases)  # reference frames keep what they stated
    hit = err < 1.0
    within = float(np.mean(hit))
    best = None
    factors = GLARE_FACTORS if np.any(glare > 0) else np.zeros(1)
    for k in factors:
        for a in scales:
            f = lambda s, a=a, k=k: mean_confidence(s, base, ref, ref_conf, a, k, glare) - within  # noqa: E731
            if f(0.0) < 0 or f(0.5) > 0:
                continue  # no spread makes this scale calibrated in the large
            s = brentq(f, 0.0, 0.5, xtol=1e-6)
            c = np.clip(stated(a, s, base, ref, ref_conf, k, glare)[~ref], 1e-9, 1 - 1e-9)
            loglik = float(np.sum(np.where(hit[~ref], np.log(c), np.log1p(-c))))
            if best is None or loglik > best[0]:
                best = (loglik, float(a), float(s), float(k))
    if best is None:  # stated below the truth even at the smallest scale and no spread
        best = (float("nan"), float(scales[0]), 0.0, 0.0)
    _, a, s, k = best
    return {"a": a, "s": s, "k": k, "within": within, "frames": int(len(err)),
            "stated_at_s": mean_confidence(s, base, ref, ref_conf, a, k, glare), "loglik": best[0]}


def as_stated(rows: list[dict]) -> list[dict]:
    """What the rows' statements say against what happened, per source and case: each row's ``source`` (the file it
    came from and whether its histories had veiling glare) and ``case``, with the frames, the mean ``confidence`` the
    model stated and the fraction of frames within 1°. A regime is chosen so that the two agree over its pooled cases
    and sources; this table shows where they part (glared against glare-free histories, one case against another)."""
    groups: dict[tuple[str, str], tuple[list[float], list[bool]]] = {}
    for r in rows:
        conf, hit = groups.setdefault((r.get("source", ""), r["case"]), ([], []))
        conf += [float(c) for c in r["confidence"]]
        hit += [float(e) < 1.0 for e in r["err"]]
    return [{"source": src, "case": case, "frames": len(conf), "stated": float(np.mean(conf)),
             "within": float(np.mean(hit))} for (src, case), (conf, hit) in groups.items()]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("rows", nargs="+",
                    help="JSON written by benchmarks/unmeasured.py (--split dev); several: their frames pooled")
    ap.add_argument("--scales-from", type=float, default=0.5,
                    help="the least Laplace scale tried (default 0.5, as the 30-frame regimes were chosen; short "
                         "histories need less)")
    args = ap.parse_args(argv)
    scales = scales_from(args.scales_from)
    rows = []
    for path in args.rows:
        try:
            d = json.loads(Path(path).read_text())
        except (OSError, ValueError) as exc:
            print(f"{path}: cannot read ({exc.__class__.__name__}: {exc})", file=sys.stderr)
            return 2
        if d.get("split") != "dev":
            print(f"{path}: split {d.get('split')!r}; choose on the development split only", file=sys.stderr)
            return 2
        if any("camera_log_gain" not in r for r in d["rows"]):
            print(f"{path}: rows without camera_log_gain (written before this tool); re-run the benchmark",
                  file=sys.stderr)
            return 2
        source = f"{Path(path).name}{' (glare)' if d.get('flare') else ''}"
        rows += [dict(r, source=source) for r in d["rows"]]
    print(f"{'regime':16} {'chosen on':28} {'frames':>6} {'within 1°':>9} {'a':>6} {'s (log)':>8} {'k':>5} "
          f"{'stated':>7}")
    for (prim, kind), cases in REGIMES.items():
        if not any(r["case"] in cases for r in rows):
            continue
        out = solve(rows, cases, scales)
        print(f"{prim + ' / ' + kind:16} {', '.join(cases):28} {out['frames']:6d} {out['within']:9.3f} "
              f"{out['a']:6.3f} {out['s']:8.4f} {out['k']:5.2f} {out['stated_at_s']:7.3f}")
    print(f"\n{'as stated now':32} {'frames':>6} {'stated':>7} {'within 1°':>9} {'gap':>7}")
    for g in as_stated(rows):  # where the pooled choice parts: glare against none, one case against another
        print(f"{g['source'] + ' ' + g['case']:32} {g['frames']:6d} {g['stated']:7.3f} {g['within']:9.3f} "
              f"{g['stated'] - g['within']:+7.3f}")
    keys = sorted({(r.get("primaries", "camera"), r["mired_key"]) for r in rows if "mired_key" in r})
    if keys:  # the temperature's spread as the model keys it (a chart read, read as rendered, or refused)
        print(f"\n{'temperature':32} {'MK⁻¹ RMS':>8} {'stated':>6} {'in 95':>5} {'add z':>5} {'add95':>5}")
        for prim, key in keys:
            sel = [r for r in rows if r.get("primaries", "camera") == prim and r.get("mired_key") == key]
            mired = mired_extra(sel)
            if mired is not None:
                print(f"{prim + ' / ' + key:32} " + "{:8.1f} {:6.1f} {:5.2f} {:5.1f} {:5.1f}".format(*mired))
    return 0


if __name__ == "__main__":
    sys.exit(main())
