"""Refit benchmark (issue 9): one camera's history of 1k / 10k / 100k frames × 16 patches, and a fleet of cameras
refitted through a Dask ``LocalCluster`` versus serially.

Run: ``python benchmarks/refit.py [--quick] [--sizes 1000,10000,100000] [--cameras 200] [--fleet-frames 200]
[--no-fleet] [--profile]``. Prints a table and writes ``benchmarks/results/refit.json``.

Each one-camera refit runs in a fresh (spawned) process whose peak resident set (``VmHWM`` of ``/proc/self/status``,
imports included; ``ru_maxrss`` where there is no ``/proc``, which on Linux carries the parent's peak over the spawn:
the parent that stored a 100k-frame history reached ~650 MiB) is reported as ``peak MiB``, with the peak reached
before the refit (``imports``: the process, its imports and the engine), by the end of the read step (``to read``)
and by the end of the fit and check (``to fit``): whatever the write step adds shows only in ``peak MiB``.
``check s`` is the tone-response check's part of ``fit+est s`` (issue 29); ``load`` the 1-minute load average after the row.
``cpu s`` is the CPU time (``time.process_time``) of ``total s``'s refit, which the machine's other load moves less
than the wall clock. Tables a fresh process would build are read from illumon's disk cache (:mod:`illumon._tables`)
when an earlier process on this machine built them; ``ILLUMON_CACHE_DIR=`` (empty) turns that off: then ``total s``
is a first refit's on a new machine. ``again s`` is the same refit run again in that process (after the peak is read):
what a long-lived service process or Dask worker pays, whose per-process tables (Planckian locus, daylight-locus Duv,
lamp lattices, lamp spectra) and lazy imports the first refit built (~0.1–0.15 s of a 2k refit's ``total s`` before
the disk cache, ~0.05 s with it).

``floor s`` is what issue 29 holds a refit against, a numpy batched solve of the same size: the camera's rows read
with ``sqlite3`` and decoded into an F × 16 × 3 array, then one weighted linear least-squares solve per frame (three
unknowns, every patch's 3 × 3 map, missing patches without weight) as batched matrix products and
``numpy.linalg.solve``; ``÷ floor`` is ``total s`` over it. ``est ms`` is the per-frame estimate after the refit with
its scene model (:func:`illumon_service.estimation.estimate_frame`, the service's cached model and solver; median
over 200 frames of the history after one warm-up), the ingest path's estimate step. ``--profile`` runs each size's
refit in this process under cProfile instead and prints illumon's 60 functions of largest cumulative time.

Each history is simulated from measured data (Nikon D5100 sensitivities, Granada daylight in sequence, 16 Munsell
reflectances, 10 % of patches missing) when ``../shared/data`` is present, from synthetic spectra otherwise. Frames
are stored straight into the service's SQLite database (not timed); the timed part is
:func:`illumon_service.refit.refit_camera` — read the history, fit the scene model (reflectances on 300 frames spread
over the illuminant range), estimate every frame, write the estimates — with the service's default settings.

Fleet: Dask is :func:`illumon_service.jobs.run_batch` (``--workers`` processes with one thread each forked from this
process, :func:`illumon_service.jobs.fork_workers`, joining a ``LocalCluster``'s scheduler, tasks carrying only camera
ids, the workers' and the cluster's start-up included); serial, run after it, is ``refit_camera`` camera after camera
in this process (after, so that the forked workers do not inherit the per-process tables the serial refits build).
``dask.distributed`` is imported before the Dask side's clock starts, as the serial side's modules are (its seconds
printed apart).
The per-camera seconds of both and the load average are printed: on a shared machine the speed-up is
bounded by the CPUs other processes leave free, and a per-camera time that grows under Dask means the workers competed
for CPUs.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import tempfile
import threading
import time
import warnings
from datetime import datetime, timedelta, timezone
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from illumon.camera import angular_error_deg  # noqa: E402
from illumon.daylight import CIEDaylight  # noqa: E402
from illumon.simulation import (
    datasets,  # noqa: E402
    simulate_history,  # noqa: E402
)
from illumon_service.jobs import run_batch, usable_cpus  # noqa: E402
from illumon_service.refit import refit_camera  # noqa: E402
from illumon_service.settings import Settings  # noqa: E402
from illumon_service.storage import Camera, Frame, make_engine, make_session_factory  # noqa: E402
from sqlalchemy import insert  # noqa: E402

RESULTS = Path(__file__).with_name("results")
N_PATCHES = 16
T0 = datetime(2025, 6, 1, tzinfo=timezone.utc)


def spectra() -> tuple[np.ndarray, np.ndarray, np.ndarray, str]:
    """(sensitivities 61 × 3, daylight D × 61, reflectances 16 × 61, provenance)."""
    rng = np.random.default_rng(0)
    if datasets.shared_data_dir() is not None:
        css = datasets.load_camera("Nikon_D5100")
        _, day = datasets.load_granada_daylight()
        _, refl = datasets.load_reflectance_set("munsell_matt_1269")
        return css, day, refl[rng.choice(len(refl), N_PATCHES, replace=False)], "measured (Nikon D5100, Granada, Munsell)"
    wl = np.arange(400, 701, 5)
    css = np.column_stack([np.exp(-0.5 * ((wl - c) / 30) ** 2) for c in (600, 540, 460)])
    mired = np.linspace(100, 250, 500)
    day = CIEDaylight().spectra(np.column_stack([mired, np.zeros_like(mired)]))
    refl = np.clip(0.2 + 0.6 * rng.random((N_PATCHES, 1)) * np.sin(wl / rng.uniform(40, 120, (N_PATCHES, 1))) ** 2, 0, 1)
    return css, day, refl, "synthetic (Gaussian sensitivities, CIE D, smooth reflectances)"


def store_camera(sessions, css: np.ndarray, day: np.ndarray, refl: np.ndarray, n: int, seed: int) -> tuple[int, np.ndarray]:
    """Simulate ``n`` frames and store them as one camera; returns (camera id, true camera white F × 3)."""
    idx = (np.arange(n) * 7 + seed * 131) % len(day)
    hist = simulate_history(css, day[idx], refl, rng=seed, missing_fraction=0.1)
    ids = [f"p{j:02d}" for j in range(N_PATCHES)]
    with sessions() as s, s.begin():
        cam = Camera(name=f"bench-{seed}", token_hash=f"{seed:064x}", sensitivities=css.tolist(),
                     regions=[{"id": p, "x": 0, "y": 0, "width": 1, "height": 1} for p in ids],
                     response={"encoding": "linear"})
        s.add(cam)
        s.flush()
        cid = cam.id
        vals = hist.observations.values
        rows = []
        for f in range(n):
            patches = {p: (None if not np.isfinite(vals[f, j, 0]) else vals[f, j].tolist()) for j, p in enumerate(ids)}
            rows.append({"camera_id": cid, "taken_at": T0 + timedelta(minutes=f), "patches": patches})
        for k in range(0, n, 20000):
            s.execute(insert(Frame), rows[k : k + 20000])
    return cid, hist.true_white


def _history_rows(url: str, cid: int, limit: int | None = None) -> list[tuple[int, str, str]]:
    """(id, taken_at, patches JSON) of a camera's frames in time order, read with ``sqlite3`` alone."""
    import sqlite3

    from sqlalchemy.engine import make_url

    con = sqlite3.connect(make_url(url).database)
    try:
        sql = "SELECT id, taken_at, patches FROM frames WHERE camera_id = ? ORDER BY taken_at"
        return con.execute(sql + (f" LIMIT {int(limit)}" if limit else ""), (cid,)).fetchall()
    finally:
        con.close()


def numpy_floor(url: str, cid: int) -> float:
    """Seconds of the floor a refit is held against (module docstring): read and decode the camera's rows, then one
    batched per-frame weighted least-squares solve."""
    t = time.perf_counter()
    rows = _history_rows(url, cid)
    ids = [f"p{j:02d}" for j in range(N_PATCHES)]
    missing = [math.nan] * 3
    flat: list[float] = []
    for _, _, patches in rows:
        d = json.loads(patches)
        for p in ids:
            flat += d[p] or missing
    y = np.array(flat).reshape(len(rows), N_PATCHES, 3)
    g = np.random.default_rng(0).uniform(0.1, 1.0, (N_PATCHES * 3, 3))  # every patch channel's row of its 3 × 3 map
    w = np.isfinite(y).reshape(len(rows), -1).astype(float)
    a = (w @ (g[:, :, None] * g[:, None, :]).reshape(-1, 9)).reshape(-1, 3, 3) + 1e-9 * np.eye(3)
    b = np.linalg.solve(a, ((w * np.nan_to_num(y.reshape(len(rows), -1))) @ g)[..., None])[..., 0]
    assert b.shape == (len(rows), 3)
    return time.perf_counter() - t


def _estimate_ms(url: str, data_dir: str, cid: int, n: int = 200) -> float:
    """Median milliseconds of one frame's estimate with the camera's new scene model (module docstring)."""
    from illumon_service.estimation import estimate_frame

    model = max((Path(data_dir) / "models").glob(f"camera-{cid}.*.json"), key=lambda q: q.stat().st_mtime_ns)
    ids = [f"p{j:02d}" for j in range(N_PATCHES)]
    times = []
    for fid, taken, patches in _history_rows(url, cid, n + 1):
        t = time.perf_counter()
        estimate_frame(data_dir, cid, str(fid), str(taken), json.loads(patches), ids, model_file=model)
        times.append(time.perf_counter() - t)
    return 1e3 * float(np.median(times[1:]))


def _peak_mib() -> float:
    """This process's peak resident set so far, MiB (module docstring)."""
    try:
        with open("/proc/self/status") as status:
            return next(int(line.split()[1]) for line in status if line.startswith("VmHWM:")) / 1024  # kB
    except (OSError, StopIteration):
        import resource

        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # KiB on Linux


def _refit_child(url: str, data_dir: str, cid: int, conn) -> None:  # noqa: ANN001 - a multiprocessing Connection
    """Child process: refit one camera; send (seconds, summary, peak RSS in MiB) back, the summary with the
    per-frame estimate's milliseconds after the refit (``estimate_ms``)."""
    warnings.simplefilter("ignore")
    settings = Settings(data_dir=data_dir, admin_token="x")
    engine = make_engine(url)
    peaks: dict[float, float] = {}

    def progress(done: float) -> None:  # the peak so far at the end of each step (read 0.1, fit + check 0.8)
        peaks[done] = _peak_mib()

    progress(0.0)
    t, cpu = time.perf_counter(), time.process_time()
    summary = refit_camera(make_session_factory(engine), cid, data_dir=Path(data_dir),
                           max_frames=settings.refit_max_frames, method=settings.refit_method,
                           max_fit_frames=settings.refit_fit_frames, progress=progress)
    seconds = time.perf_counter() - t
    summary["cpu_s"] = time.process_time() - cpu
    summary["peak_mib_steps"] = {"start": peaks.get(0.0), "read": peaks.get(0.1), "fit": peaks.get(0.8)}
    peak = _peak_mib()
    t = time.perf_counter()  # the same refit again: a service process's per-process tables are built by now
    refit_camera(make_session_factory(engine), cid, data_dir=Path(data_dir), max_frames=settings.refit_max_frames,
                 method=settings.refit_method, max_fit_frames=settings.refit_fit_frames)
    summary["again_s"] = time.perf_counter() - t
    engine.dispose()
    summary["estimate_ms"] = _estimate_ms(url, data_dir, cid)
    conn.send((seconds, summary, peak))
    conn.close()


def refit_in_child(settings: Settings, cid: int, data_dir: Path) -> tuple[float, dict, float]:
    """``refit_camera`` in a fresh (spawned) process, so that its peak memory is the refit's own (plus the imports):
    returns (seconds, summary, peak resident set in MiB)."""
    import multiprocessing as mp

    ctx = mp.get_context("spawn")
    parent, child = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=_refit_child, args=(settings.resolved_database_url, str(data_dir), cid, child))
    proc.start()
    child.close()
    seconds, summary, peak = parent.recv()
    proc.join()
    return seconds, summary, peak


def one_camera(sizes: list[int], css, day, refl) -> list[dict]:
    """Time refit_camera on histories of the given lengths."""
    out = []
    for n in sizes:
        with tempfile.TemporaryDirectory() as tmp:
            settings = Settings(data_dir=tmp, admin_token="x")
            engine = make_engine(settings.resolved_database_url)
            sessions = make_session_factory(engine)
            cid, truth = store_camera(sessions, css, day, refl, n, seed=1)
            engine.dispose()
            seconds, summary, peak_mib = refit_in_child(settings, cid, Path(tmp))
            floor = min(numpy_floor(settings.resolved_database_url, cid) for _ in range(2))  # the second warm
            engine = make_engine(settings.resolved_database_url)
            sessions = make_session_factory(engine)
            with sessions() as s:
                from illumon_service.storage import Estimate
                from sqlalchemy import select

                got = s.execute(select(Estimate.frame_id, Estimate.white_rgb).where(Estimate.camera_id == cid)
                                .order_by(Estimate.frame_id)).all()
            white = np.array([w for _, w in got])
            err = angular_error_deg(white, truth[[fid - 1 for fid, _ in got]])
            engine.dispose()
        row = {"frames": n, "patches": N_PATCHES, "seconds": seconds, "read_s": summary["read_s"],
               "fit_estimate_s": summary["fit_s"], "response_check_s": summary.get("response_check_s", float("nan")),
               "write_s": summary["write_s"], "estimated": summary["frames"], "peak_mib": peak_mib,
               "peak_mib_start": summary["peak_mib_steps"]["start"], "peak_mib_read": summary["peak_mib_steps"]["read"],
               "peak_mib_fit": summary["peak_mib_steps"]["fit"],
               "median_deg": float(np.median(err)), "p95_deg": float(np.percentile(err, 95)),
               "floor_s": floor, "floor_ratio": seconds / floor, "estimate_ms": summary["estimate_ms"],
               "again_s": summary["again_s"], "cpu_s": summary["cpu_s"]}
        out.append(row)
        print(f"{n:>7d} {seconds:8.2f} {row['read_s']:7.2f} {row['fit_estimate_s']:9.2f} {row['response_check_s']:8.2f} "
              f"{row['write_s']:7.2f} {floor:7.3f} {row['floor_ratio']:7.1f} {row['estimate_ms']:6.2f} "
              f"{row['peak_mib_start']:7.0f} {row['peak_mib_read']:7.0f} {row['peak_mib_fit']:7.0f} "
              f"{peak_mib:8.0f} {row['median_deg']:7.3f} {row['p95_deg']:7.3f} {row['again_s']:7.2f} "
              f"{row['cpu_s']:6.2f} {os.getloadavg()[0]:5.1f}", flush=True)
    return out


def profile_refit(n: int, css, day, refl, top: int = 60) -> None:
    """``refit_camera`` of an ``n``-frame history in this process under cProfile: illumon's ``top`` functions by
    cumulative time (``--profile``; imports and the process start excluded)."""
    import cProfile
    import pstats

    with tempfile.TemporaryDirectory() as tmp:
        settings = Settings(data_dir=tmp, admin_token="x")
        engine = make_engine(settings.resolved_database_url)
        sessions = make_session_factory(engine)
        cid, _ = store_camera(sessions, css, day, refl, n, seed=1)
        prof = cProfile.Profile()
        t = time.perf_counter()
        prof.enable()
        summary = refit_camera(sessions, cid, data_dir=Path(tmp), max_frames=settings.refit_max_frames,
                               method=settings.refit_method, max_fit_frames=settings.refit_fit_frames)
        prof.disable()
        print(f"{n} frames: refit_camera {time.perf_counter() - t:.2f} s under cProfile (read {summary['read_s']} s, "
              f"fit {summary['fit_s']} s, write {summary['write_s']} s; load {os.getloadavg()[0]:.1f})")
        pstats.Stats(prof).sort_stats("cumulative").print_stats("illumon", top)
        engine.dispose()


def fleet(cameras: int, frames: int, workers: int, css, day, refl) -> dict:
    """Refit ``cameras`` cameras of ``frames`` frames each serially, then through a Dask LocalCluster."""
    out: dict = {"cameras": cameras, "frames_per_camera": frames, "dask_workers": workers}
    with tempfile.TemporaryDirectory() as tmp:
        settings = Settings(data_dir=tmp, admin_token="x")
        engine = make_engine(settings.resolved_database_url)
        sessions = make_session_factory(engine)
        ids = [store_camera(sessions, css, day, refl, frames, seed=s)[0] for s in range(cameras)]
        engine.dispose()
        # Dask first: run_batch forks its workers from this process (jobs.fork_workers), which must not have built
        # the per-process tables of a refit before (the serial part would build them: `illumon refit --all` starts
        # without them, and so does each of its workers).
        load0 = os.getloadavg()[0]
        # Like for like: the serial side's modules (illumon, the service's refit) are imported before its clock
        # starts, so Dask's are too — once per process, as `illumon refit --all` or the service pays them at start
        # (~0.2–0.3 s; printed apart). The import starts no thread, so the workers are still forked.
        t = time.perf_counter()
        import dask.distributed  # noqa: F401
        out["dask_import_s"] = time.perf_counter() - t
        out["workers_forked"] = threading.active_count() == 1  # else run_batch spawns them (jobs.fork_workers)
        t = time.perf_counter()
        results = run_batch(settings, ids, n_workers=workers, progress=False)
        out["dask_s"] = time.perf_counter() - t
        out["dask_failures"] = sum("error" in r for r in results)
        load1 = os.getloadavg()[0]
        t = time.perf_counter()
        serial = []
        for cid in ids:
            engine = make_engine(settings.resolved_database_url)
            serial.append(refit_camera(make_session_factory(engine), cid, data_dir=Path(tmp),
                                       max_fit_frames=settings.refit_fit_frames))
            engine.dispose()
        out["serial_s"] = time.perf_counter() - t
        # Per-camera seconds inside refit_camera: equal on both sides unless the workers compete for CPUs.
        out["serial_camera_s"] = float(np.mean([r["seconds"] for r in serial]))
        out["dask_camera_s"] = float(np.mean([r["seconds"] for r in results if "seconds" in r] or [np.nan]))
        out["load_dask"], out["load_serial"] = (load0 + load1) / 2, (load1 + os.getloadavg()[0]) / 2
    out["speedup"] = out["serial_s"] / out["dask_s"]
    return out


def main() -> None:
    """Run the benchmark; print the tables; write the JSON."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="1k and 10k frames; 20 cameras × 100 frames")
    parser.add_argument("--sizes", help="comma-separated history lengths (1000,10000,100000)")
    parser.add_argument("--cameras", type=int, help="fleet size (200)")
    parser.add_argument("--fleet-frames", type=int, help="frames per fleet camera (200)")
    parser.add_argument("--workers", type=int, default=usable_cpus(), help="Dask worker processes (usable CPUs)")
    parser.add_argument("--no-fleet", action="store_true", help="one camera only")
    parser.add_argument("--profile", action="store_true",
                        help="cProfile each size's refit in this process and print its top functions instead")
    args = parser.parse_args()
    warnings.simplefilter("ignore")
    sizes = [int(v) for v in args.sizes.split(",")] if args.sizes else ([1000, 10000] if args.quick else [1000, 10000, 100000])
    cameras = args.cameras or (20 if args.quick else 200)
    fleet_frames = args.fleet_frames or (100 if args.quick else 200)
    css, day, refl, provenance = spectra()
    if args.profile:
        for n in sizes:
            profile_refit(n, css, day, refl)
        return
    print(f"data: {provenance}; CPUs: {os.cpu_count()}")
    print("\none camera, 16 patches: refit (read + scene model fit + estimate every frame + write)")
    print(f"{'frames':>7} {'total s':>8} {'read s':>7} {'fit+est s':>9} {'check s':>8} {'write s':>7} {'floor s':>7} "
          f"{'÷ floor':>7} {'est ms':>6} {'imports':>7} {'to read':>7} {'to fit':>7} {'peak MiB':>8} {'med °':>7} "
          f"{'p95 °':>7} {'again s':>7} {'cpu s':>6} {'load':>5}")
    single = one_camera(sizes, css, day, refl)
    if args.no_fleet:
        RESULTS.mkdir(exist_ok=True)
        (RESULTS / "refit.json").write_text(json.dumps({"data": provenance, "cpus": os.cpu_count(),
                                                        "one_camera": single}, indent=1) + "\n")
        print(f"\nwrote {RESULTS / 'refit.json'}")
        return
    print(f"\nfleet: {cameras} cameras × {fleet_frames} frames × 16 patches")
    fl = fleet(cameras, fleet_frames, args.workers, css, day, refl)
    print(f"{'serial s':>9} {'Dask s':>8} {'workers':>8} {'speed-up':>9} {'failures':>9} {'s/cam ser':>9} {'s/cam Dask':>10} "
          f"{'load ser':>8} {'load Dask':>9}")
    print(f"{fl['serial_s']:9.1f} {fl['dask_s']:8.1f} {fl['dask_workers']:8d} {fl['speedup']:9.2f} {fl['dask_failures']:9d} "
          f"{fl['serial_camera_s']:9.2f} {fl['dask_camera_s']:10.2f} {fl['load_serial']:8.1f} {fl['load_dask']:9.1f}")
    print("s/cam: mean seconds of one camera's refit inside refit_camera; load: 1-min load average during each part "
          f"(other processes included; {os.cpu_count()} CPUs); workers {'forked' if fl['workers_forked'] else 'spawned'}; "
          f"dask.distributed imported before the Dask clock in {fl['dask_import_s']:.2f} s")
    RESULTS.mkdir(exist_ok=True)
    out = {"data": provenance, "cpus": os.cpu_count(), "one_camera": single, "fleet": fl}
    (RESULTS / "refit.json").write_text(json.dumps(out, indent=1) + "\n")
    print(f"\nwrote {RESULTS / 'refit.json'}")


if __name__ == "__main__":
    main()
