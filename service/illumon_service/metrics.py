"""In-process metrics rendered in the Prometheus text exposition format (no client library needed)."""

from __future__ import annotations

import threading
from collections import defaultdict

__all__ = ["Metrics"]


class Metrics:
    """Counters and summaries (sum / count / max) keyed by name and label string; thread-safe."""

    HELP = {
        "illumon_frames_ingested_total": ("counter", "Frames stored (images and JSON observations)."),
        "illumon_estimate_seconds": ("summary", "Per-frame estimation latency at ingest."),
        "illumon_ingest_seconds": ("summary", "Whole ingest latency: decode, region statistics, estimate, commit."),
        "illumon_ingest_stage_seconds": ("summary", "Ingest stages: receive (upload and multipart), decode, regions, "
                                                    "estimate, commit."),
        "illumon_ingest_commit_frames": ("summary", "Frames per ingest commit (group commit: one transaction, one fsync)."),
        "illumon_ingest_decodes_total": ("counter", "Decoded frames by scale (1/1 full size; 1/2, 1/4, 1/8 reduced JPEG)."),
        "illumon_refit_seconds": ("summary", "Refit job durations."),
        "illumon_refit_total": ("counter", "Refit jobs by outcome."),
        "illumon_http_errors_total": ("counter", "Error responses by status code."),
    }

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._counters: dict[tuple[str, str], float] = defaultdict(float)
        self._summaries: dict[tuple[str, str], list[float]] = {}

    def inc(self, name: str, value: float = 1.0, labels: str = "") -> None:
        """Add ``value`` to counter ``name{labels}``."""
        with self._lock:
            self._counters[(name, labels)] += value

    def observe(self, name: str, value: float, labels: str = "") -> None:
        """Record one observation of summary ``name{labels}``."""
        with self._lock:
            s = self._summaries.setdefault((name, labels), [0.0, 0.0, 0.0])
            s[0] += value
            s[1] += 1
            s[2] = max(s[2], value)

    def render(self) -> str:
        """Prometheus text format (version 0.0.4)."""
        lines: list[str] = []
        with self._lock:
            counters = dict(self._counters)
            summaries = {k: list(v) for k, v in self._summaries.items()}
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
