"""Service metrics rendered in the Prometheus text exposition format (no client library needed).

One process keeps its counters and summaries in memory. Several worker processes (``illumon serve --workers N``)
each publish a snapshot to a shared folder (``<pid>.json``, replaced atomically, at most every second while
metrics change and at every scrape), and ``/metrics`` — answered by whichever worker gets the request — sums the
snapshots of all of them: counters and summary sums and counts add, maxima take the largest. ``illumon serve``
empties the folder before it starts the workers, so the figures count from that start, as for one process.
"""

from __future__ import annotations

import json
import os
import threading
import time
from collections import defaultdict
from pathlib import Path

__all__ = ["Metrics"]


class Metrics:
    """Counters and summaries (sum / count / max) keyed by name and label string; thread-safe; optionally summed
    over processes that share a folder (see module docstring)."""

    HELP = {
        "illumon_frames_ingested_total": ("counter", "Frames stored (images and JSON observations)."),
        "illumon_estimate_seconds": ("summary", "Per-frame estimation latency at ingest."),
        "illumon_ingest_seconds": ("summary", "Whole ingest latency: decode, region statistics, estimate, commit."),
        "illumon_ingest_stage_seconds": ("summary", "Ingest stages: receive (upload and multipart), decode, register "
                                                    "(thumbnail and registration), regions (the wait for the region "
                                                    "statistics after it), estimate, commit."),
        "illumon_ingest_commit_frames": ("summary", "Frames per ingest commit (group commit: one transaction, one fsync)."),
        "illumon_ingest_decodes_total": ("counter", "Decoded frames by scale (1/1 full size; 1/2, 1/4, 1/8 reduced JPEG)."),
        "illumon_refit_seconds": ("summary", "Refit job durations."),
        "illumon_refit_total": ("counter", "Refit jobs by outcome."),
        "illumon_http_errors_total": ("counter", "Error responses by status code."),
    }

    def __init__(self, publish_dir: Path | None = None, *, process_id: str | None = None,
                 interval: float = 1.0) -> None:
        """``publish_dir``: the folder shared by worker processes (``None``: this process alone); ``process_id``
        names this process's snapshot (its pid by default); ``interval``: seconds between publications."""
        self._lock = threading.Lock()
        self._counters: dict[tuple[str, str], float] = defaultdict(float)
        self._summaries: dict[tuple[str, str], list[float]] = {}
        self._dir = Path(publish_dir) if publish_dir is not None else None
        self._id = process_id or str(os.getpid())
        self._changes = 0
        self._published = -1
        if self._dir is not None:
            self._dir.mkdir(parents=True, exist_ok=True)
            threading.Thread(target=self._publish_loop, args=(interval,), name="metrics-publish", daemon=True).start()

    def inc(self, name: str, value: float = 1.0, labels: str = "") -> None:
        """Add ``value`` to counter ``name{labels}``."""
        with self._lock:
            self._counters[(name, labels)] += value
            self._changes += 1

    def observe(self, name: str, value: float, labels: str = "") -> None:
        """Record one observation of summary ``name{labels}``."""
        with self._lock:
            s = self._summaries.setdefault((name, labels), [0.0, 0.0, 0.0])
            s[0] += value
            s[1] += 1
            s[2] = max(s[2], value)
            self._changes += 1

    def _snapshot(self) -> tuple[int, dict]:
        with self._lock:
            return self._changes, {
                "counters": [[n, lab, v] for (n, lab), v in self._counters.items()],
                "summaries": [[n, lab, *v] for (n, lab), v in self._summaries.items()],
            }

    def publish(self) -> None:
        """Write this process's snapshot to the shared folder (atomic replace); nothing without a folder."""
        if self._dir is None:
            return
        changes, snap = self._snapshot()
        if changes == self._published:
            return
        tmp = self._dir / f".{self._id}.{threading.get_ident()}.tmp"  # a scrape and the publisher thread may race
        tmp.write_text(json.dumps(snap))
        os.replace(tmp, self._dir / f"{self._id}.json")
        self._published = changes

    def _publish_loop(self, interval: float) -> None:
        while True:
            time.sleep(interval)
            try:
                self.publish()
            except OSError:  # a full or vanished folder must not stop the service; the next scrape retries
                pass

    def _merged(self) -> tuple[dict[tuple[str, str], float], dict[tuple[str, str], list[float]]]:
        """This process's metrics plus the published snapshots of the other processes."""
        with self._lock:
            counters: dict[tuple[str, str], float] = defaultdict(float, self._counters)
            summaries = {k: list(v) for k, v in self._summaries.items()}
        if self._dir is None:
            return counters, summaries
        self.publish()
        for path in self._dir.glob("*.json"):
            if path.stem == self._id:
                continue
            try:
                snap = json.loads(path.read_text())
            except (OSError, ValueError):  # replaced or removed while reading: skip this scrape
                continue
            for n, lab, v in snap.get("counters", []):
                counters[(n, lab)] += v
            for n, lab, total, count, peak in snap.get("summaries", []):
                s = summaries.setdefault((n, lab), [0.0, 0.0, 0.0])
                s[0] += total
                s[1] += count
                s[2] = max(s[2], peak)
        return counters, summaries

    def render(self) -> str:
        """Prometheus text format (version 0.0.4), summed over the worker processes that publish to the folder."""
        lines: list[str] = []
        counters, summaries = self._merged()
        for name, (kind, text) in self.HELP.items():
            lines.append(f"# HELP {name} {text}")
            lines.append(f"# TYPE {name} {kind}")
            if kind == "counter":
                rows = {k: v for k, v in counters.items() if k[0] == name} or {(name, ""): 0.0}
                for (_, lab), v in sorted(rows.items()):
                    lines.append(f"{name}{'{' + lab + '}' if lab else ''} {v:g}")
            else:
                for (n, lab), (total, count, peak) in sorted(summaries.items()):
                    if n != name:
                        continue
                    suffix = "{" + lab + "}" if lab else ""
                    lines.append(f"{name}_sum{suffix} {total:.6g}")
                    lines.append(f"{name}_count{suffix} {count:g}")
                    lines.append(f"{name}_max{suffix} {peak:.6g}")
        return "\n".join(lines) + "\n"
