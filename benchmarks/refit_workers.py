"""Where a fleet refit's time goes in Dask workers (issue 29): one camera's refit in this process, in plain spawned
processes and in Dask ``LocalCluster`` workers, with the CPU time and page faults of each.

Run: ``python benchmarks/refit_workers.py [--cameras 8] [--frames 1000] [--modes serial,plain1,dask1,dask-default1]
[--env MALLOC_TRIM_THRESHOLD_=65536]``. Modes, run in the order given on the same stored cameras: ``serial`` (this
process), ``plainK`` (K spawned processes sharing the cameras; ``--env`` variables set in their environment),
``daskK`` (K workers with the service's configuration, :func:`illumon_service.jobs.worker_config`),
``dask-defaultK`` (K workers with Dask's defaults) and ``forkK`` (K workers forked from this process as
:func:`illumon_service.jobs.run_batch` forks them; before any ``dask`` mode, which leaves threads behind, and
first for workers as cold as ``run_batch``'s: after ``serial`` they inherit the tables its refits built). Each
line gives the wall time (Dask's includes the cluster's
start-up, also shown), and per camera the seconds inside ``refit_camera``, the CPU seconds of the task's thread and
of its whole process while it ran, and the minor page faults of the process while it ran (``ru_minflt``; a count,
so it does not move with the machine's load as the seconds do). Histories as ``benchmarks/refit.py`` stores them.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import resource
import tempfile
import time
import warnings

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from illumon_service.jobs import _refit_worker, worker_config  # noqa: E402
from illumon_service.settings import Settings  # noqa: E402
from illumon_service.storage import make_engine, make_session_factory  # noqa: E402
from refit import spectra, store_camera  # noqa: E402


def task(url: str, cid: int, data_dir: str) -> dict:
    """One camera's refit as a Dask task runs it, with its CPU time and the process's page faults."""
    t0, c0 = time.thread_time(), time.process_time()
    f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    summary = _refit_worker(url, cid, data_dir, 100_000, "model", 300)
    return {"seconds": summary["seconds"], "thread_cpu": time.thread_time() - t0,
            "process_cpu": time.process_time() - c0, "faults": resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0}


def _plain(url: str, data_dir: str, ids: list[int], queue) -> None:  # noqa: ANN001 - a multiprocessing Queue
    warnings.simplefilter("ignore")
    queue.put([task(url, cid, data_dir) for cid in ids])


def run_plain(url: str, data_dir: str, ids: list[int], k: int, env: dict[str, str]) -> list[dict]:
    """The cameras shared among ``k`` spawned processes started with ``env`` in their environment."""
    ctx = mp.get_context("spawn")
    queue = ctx.Queue()
    saved = {v: os.environ.get(v) for v in env}
    os.environ.update(env)
    try:
        procs = [ctx.Process(target=_plain, args=(url, data_dir, ids[i::k], queue)) for i in range(k)]
        for p in procs:
            p.start()
    finally:
        for v, old in saved.items():
            if old is None:
                os.environ.pop(v, None)
            else:
                os.environ[v] = old
    out = [r for _ in procs for r in queue.get()]
    for p in procs:
        p.join()
    return out


def run_dask(url: str, data_dir: str, ids: list[int], k: int, service: bool) -> tuple[float, list[dict]]:
    """The cameras as tasks of a ``LocalCluster`` of ``k`` one-thread workers; (start-up seconds, results)."""
    import dask
    from dask.distributed import Client, LocalCluster

    t = time.perf_counter()
    environ = dict(os.environ)
    with dask.config.set(worker_config() if service else {}):
        cluster = LocalCluster(n_workers=k, threads_per_worker=1, processes=True, dashboard_address=None)
    os.environ.clear()  # the nanny sets its workers' variables in this process's environment too: later modes
    os.environ.update(environ)  # would inherit them
    client = Client(cluster)
    return _gather(client, url, data_dir, ids, time.perf_counter() - t, cluster.close)


def _gather(client, url: str, data_dir: str, ids: list[int], start: float, *closers) -> tuple[float, list[dict]]:  # noqa: ANN001
    """The cameras as tasks of ``client``'s workers: (``start``, results); the client and then ``closers`` closed."""
    try:
        return start, client.gather([client.submit(task, url, cid, data_dir, pure=False) for cid in ids])
    finally:
        client.close()
        for close in closers:
            close()


def run_forked(url: str, data_dir: str, ids: list[int], k: int) -> tuple[float, list[dict]]:
    """The cameras as tasks of ``k`` workers forked from this process joining a scheduler-only ``LocalCluster``,
    as :func:`illumon_service.jobs.run_batch` runs them (:func:`illumon_service.jobs.fork_workers`; only while this
    process runs one thread: give ``forkK`` before any ``dask`` mode); (start-up seconds, results)."""
    from dask.distributed import Client, LocalCluster
    from illumon_service.jobs import _end_forked, fork_workers

    t = time.perf_counter()
    forked = fork_workers(k)
    if not forked:
        raise SystemExit("forkK: this process runs more than one thread (give forkK before the dask modes)")
    cluster = LocalCluster(n_workers=0, threads_per_worker=1, processes=True, dashboard_address=None)
    for _, conn in forked:
        conn.send(cluster.scheduler_address)
    client = Client(cluster)
    client.wait_for_workers(k)
    return _gather(client, url, data_dir, ids, time.perf_counter() - t, cluster.close, lambda: _end_forked(forked))


def main() -> None:
    """Store the cameras, run the modes, print a line each."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cameras", type=int, default=8)
    parser.add_argument("--frames", type=int, default=1000)
    parser.add_argument("--modes", default="serial,plain1,dask1,dask-default1,plain2,dask2")
    parser.add_argument("--env", action="append", default=[], help="VAR=VALUE for the plain processes")
    args = parser.parse_args()
    warnings.simplefilter("ignore")
    env = dict(e.split("=", 1) for e in args.env)
    data_dir = tempfile.mkdtemp()
    url = Settings(data_dir=data_dir, admin_token="x").resolved_database_url
    engine = make_engine(url)
    css, day, refl, _ = spectra()
    ids = [store_camera(make_session_factory(engine), css, day, refl, args.frames, seed=s)[0]
           for s in range(args.cameras)]
    engine.dispose()
    print(f"{args.cameras} cameras × {args.frames} frames × 16 patches; {os.cpu_count()} CPUs")
    for mode in args.modes.split(","):
        t = time.perf_counter()
        start = None
        if mode == "serial":
            results = [task(url, cid, data_dir) for cid in ids]
        elif mode.startswith("plain"):
            results = run_plain(url, data_dir, ids, int(mode[5:]), env)
            mode += f" {' '.join(args.env)}" if env else ""
        elif mode.startswith("fork"):
            start, results = run_forked(url, data_dir, ids, int(mode[4:]))
        elif mode.startswith("dask-default"):
            start, results = run_dask(url, data_dir, ids, int(mode[12:]), service=False)
        else:
            start, results = run_dask(url, data_dir, ids, int(mode[4:]), service=True)
        wall = time.perf_counter() - t
        mean = {k: float(np.mean([r[k] for r in results])) for k in results[0]}
        print(f"{mode:<16} {wall:6.1f} s" + (f" (start-up {start:.1f} s)" if start is not None else "")
              + f"; a camera: {mean['seconds']:.2f} s, task thread CPU {mean['thread_cpu']:.2f} s, process CPU "
              f"{mean['process_cpu']:.2f} s, page faults {mean['faults']:.0f}; load {os.getloadavg()[0]:.1f}",
              flush=True)


if __name__ == "__main__":
    main()
