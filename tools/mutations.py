"""Deliberate bugs, one at a time: apply each mutation to the source, run the tests that should catch it, restore.

Run from the repository root (issue 30)::

    nice python tools/mutations.py [--only NAME[,NAME…]] [--list]

Each mutation replaces one exact snippet (it must occur exactly once in its file, so a stale mutation reports
``pattern not found`` instead of testing nothing), then runs its targeted tests with ``pytest -x -q``; the mutation is
*caught* when pytest fails. The file is restored in a ``finally`` block whatever happens. The table printed at the end
is the one the issue asks for: mutation, file, tests run, caught or survived, seconds.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


@dataclass(frozen=True)
class Mutation:
    """One deliberate bug: ``old`` replaced by ``new`` in ``path``; ``tests`` are pytest arguments."""

    name: str
    path: str
    old: str
    new: str
    tests: tuple[str, ...]
    origin: str = "ours"


MUTATIONS: tuple[Mutation, ...] = (
    # --- the five that survived the audit (issue 30) ---
    Mutation("c2 typo in planck_locus", "core/illumon/daylight/ohno2013.py", "    c2 = 1.4388e-2\n", "    c2 = 1.4398e-2\n",
             ("tests/core/daylight/test_ohno2013.py",), "audit"),
    Mutation("reflectance 0-1 penalty dropped from JointProblem.residuals", "core/illumon/retrieval/joint.py",
             "hinge = self.bound_weight * (np.clip(-refl, 0, None) + np.clip(refl - 1.0, 0, None))",
             "hinge = 0.0 * (np.clip(-refl, 0, None) + np.clip(refl - 1.0, 0, None))",
             ("tests/core/retrieval/test_retrieval.py",), "audit"),
    Mutation("JointProblem noise weights uniform", "core/illumon/retrieval/joint.py",
             "0.0, 1.0 / np.sqrt(var))", "0.0, 1.0 + 0.0 * var)",
             ("tests/core/retrieval/test_retrieval.py",), "audit"),
    Mutation("diagnosis: off-locus / fluorescence priority reversed", "core/illumon/diagnosis/fit.py",
             "            chosen = ok[0]\n", "            chosen = ok[-1]\n",
             ("tests/core/diagnosis/test_diagnosis.py", "-k", "priority"), "audit"),
    Mutation("diagnosis: bilinear margins halved", "core/illumon/diagnosis/fit.py",
             "    ok = [c for c in bil if c.score < -margins[c.effect]]\n",
             "    ok = [c for c in bil if c.score < -0.5 * margins[c.effect]]\n",
             ("tests/core/diagnosis/test_diagnosis.py", "-k", "below_the_margin"), "audit"),
    # --- ours: core ---
    Mutation("gains inverted (white / white_g)", "core/illumon/camera/formation.py",
             "    return w[..., 1:2] / w\n", "    return w / w[..., 1:2]\n",
             ("tests/service/test_e2e.py",)),
    Mutation("angular error in radians", "core/illumon/camera/formation.py",
             "    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))\n",
             "    return np.arccos(np.clip(cos, -1.0, 1.0))\n",
             ("tests/core/camera/test_camera.py",)),
    Mutation("Duv sign flipped (locus normal points below)", "core/illumon/daylight/ohno2013.py",
             "    normal *= np.sign(normal[:, 1:2])\n", "    normal *= -np.sign(normal[:, 1:2])\n",
             ("tests/core/daylight/test_ohno2013.py",)),
    Mutation("sRGB decode exponent 2.4 -> 2.2", "core/illumon/camera/pipeline.py",
             "((v + 0.055) / 1.055) ** 2.4)", "((v + 0.055) / 1.055) ** 2.2)",
             ("tests/core/camera/test_camera.py",)),
    Mutation("joint: daylight prior dropped", "core/illumon/retrieval/joint.py",
             "self.model.prior_residuals(params).ravel(), hinge.ravel()",
             "0.0 * self.model.prior_residuals(params).ravel(), hinge.ravel()",
             ("tests/core/retrieval/test_retrieval.py",)),
    Mutation("near-white values not censored", "core/illumon/retrieval/common.py",
             "(values >= NEAR_WHITE * white)", "(values >= 2.0 * NEAR_WHITE * white)",
             ("tests/core/retrieval/test_censoring.py",)),
    Mutation("gray-world baseline: red and blue swapped", "core/illumon/retrieval/__init__.py",
             "    chrom = np.log(whites[:, [0, 2]] / whites[:, 1:2])\n",
             "    chrom = np.log(whites[:, [2, 0]] / whites[:, 1:2])\n",
             ("tests/core/retrieval/test_retrieval.py",)),
    Mutation("undo_applied multiplies the exposure back", "core/illumon/camera/pipeline.py",
             "        y = y / (k[..., None, None] if k.ndim == 1 and y.ndim == 3 else k)\n",
             "        y = y * (k[..., None, None] if k.ndim == 1 and y.ndim == 3 else k)\n",
             ("tests/core/camera/test_camera.py",)),
    # --- ours: service ---
    Mutation("service decode: BGR not swapped to RGB", "service/illumon_service/decode.py",
             "    elif img.shape[2] == 3:\n        img = img[:, :, ::-1]\n",
             "    elif img.shape[2] == 3:\n        img = img[:, :, :]\n",
             ("tests/service/test_frames.py",)),
    Mutation("service: a camera token reads any camera", "service/illumon_service/deps.py",
             "    if not principal.admin and principal.camera_id != camera_id:\n",
             "    if not principal.admin and principal.camera_id == -camera_id:\n",
             ("tests/service/test_cameras.py",)),
)


def run(m: Mutation, python: str) -> tuple[str, float, str]:
    """Apply ``m``, run its tests, restore; the verdict, the seconds the tests took and the first failing test."""
    path = ROOT / m.path
    original = path.read_text()
    if original.count(m.old) != 1:
        return f"pattern not found ({original.count(m.old)}×)", 0.0, ""
    t = time.perf_counter()
    try:
        path.write_text(original.replace(m.old, m.new))
        env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONDONTWRITEBYTECODE": "1"}
        proc = subprocess.run([python, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider", "-m", "",
                               *m.tests], cwd=ROOT, env=env, capture_output=True, text=True)
    finally:
        path.write_text(original)
    seconds = time.perf_counter() - t
    failed = next((line.split(" ", 1)[1].split(" - ")[0] for line in proc.stdout.splitlines()
                   if line.startswith("FAILED ")), "")
    if proc.returncode == 1:
        return "caught", seconds, failed.rsplit("::", 1)[-1]
    if proc.returncode == 0:
        return "SURVIVED", seconds, ""
    return f"error (pytest exit {proc.returncode})", seconds, ""


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--only", help="comma-separated substrings of mutation names")
    ap.add_argument("--list", action="store_true", help="list the mutations and exit")
    args = ap.parse_args()
    chosen = [m for m in MUTATIONS if not args.only or any(s in m.name for s in args.only.split(","))]
    if args.list:
        for m in chosen:
            print(f"{m.origin:<6} {m.name:<58} {m.path}  [{' '.join(m.tests)}]")
        return 0
    python = sys.executable
    rows = []
    print(f"{'#':>2} {'origin':<6} {'mutation':<58} {'tests':<44} {'verdict':<10} {'s':>6}  first failing test",
          flush=True)
    for i, m in enumerate(chosen, 1):
        verdict, seconds, failed = run(m, python)
        rows.append((m, verdict))
        print(f"{i:>2} {m.origin:<6} {m.name:<58} {' '.join(m.tests):<44} {verdict:<10} {seconds:6.1f}  {failed}",
              flush=True)
    caught = sum(v == "caught" for _, v in rows)
    print(f"\n{caught} of {len(rows)} mutations caught")
    return 0 if caught == len(rows) else 1


if __name__ == "__main__":
    sys.exit(main())
