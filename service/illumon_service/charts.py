"""Server-side SVG time charts for the status page (no JavaScript, no external assets).

A chart is an ``<svg>`` with a ``viewBox`` (the page's CSS gives it ``width: 100%``), one polyline per series, an
optional shaded band per series (an interval, drawn where it is known), both broken at gaps much longer than the usual
spacing of the points (:func:`gap_breaks`), horizontal reference lines, "nice" value
ticks and UTC time ticks. Colours come from CSS classes (``series-0`` …, ``band-0`` …, ``ref``), so a Content
Security Policy without inline styles holds.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from datetime import datetime, timezone
from html import escape

from markupsafe import Markup

__all__ = ["Series", "time_chart", "nice_ticks", "time_ticks", "gap_breaks", "GAP_FACTOR"]

WIDTH, HEIGHT = 720, 230
LEFT, RIGHT, TOP, BOTTOM = 64, 14, 26, 30


@dataclass
class Series:
    """A named series: values over time, with an optional band (``lo``, ``hi``; ``None`` where unknown)."""

    name: str
    times: Sequence[datetime]
    values: Sequence[float]
    lo: Sequence[float | None] | None = None
    hi: Sequence[float | None] | None = None
    css: str = "series-0"
    band_css: str = "band-0"


@dataclass
class _Frame:
    t0: float
    t1: float
    y0: float
    y1: float
    w: float = WIDTH
    h: float = HEIGHT
    refs: list[float] = field(default_factory=list)

    def x(self, t: float) -> float:
        return LEFT + (t - self.t0) / (self.t1 - self.t0) * (self.w - LEFT - RIGHT)

    def y(self, v: float) -> float:
        return self.h - BOTTOM - (v - self.y0) / (self.y1 - self.y0) * (self.h - TOP - BOTTOM)


def nice_ticks(lo: float, hi: float, n: int = 5) -> list[float]:
    """About ``n`` round tick values (1, 2, 2.5 or 5 × 10^k apart) covering ``lo``…``hi``."""
    if not (math.isfinite(lo) and math.isfinite(hi)) or hi <= lo:
        return [lo]
    raw = (hi - lo) / max(1, n)
    mag = 10 ** math.floor(math.log10(raw))
    step = mag * min((1, 2, 2.5, 5, 10), key=lambda m: abs(m * mag - raw))
    first = math.ceil(lo / step - 1e-9) * step
    out = []
    v = first
    while v <= hi + 1e-9 * step:
        out.append(round(v, 12))
        v += step
    return out


_TIME_STEPS = [m * 60 for m in (5, 10, 15, 30, 60, 120, 180, 360, 720, 1440, 2880, 10080)]


def time_ticks(t0: float, t1: float, n: int = 6) -> tuple[list[float], Callable[[float], str]]:
    """Round UTC tick positions (POSIX seconds) over ``t0``…``t1`` and a label formatter.

    Labels are ``HH:MM`` with ``MM-DD`` at midnight for steps under a day, ``MM-DD`` for steps of days, and
    ``YYYY-MM-DD`` when the span exceeds half a year.
    """
    span = max(t1 - t0, 1.0)
    step = next((s for s in _TIME_STEPS if span / s <= n), _TIME_STEPS[-1] * math.ceil(span / n / _TIME_STEPS[-1]))
    first = math.ceil(t0 / step) * step
    ticks = []
    t = first
    while t <= t1:
        ticks.append(float(t))
        t += step
    day = 86400

    def label(v: float) -> str:
        d = datetime.fromtimestamp(v, tz=timezone.utc)
        if span > 183 * day:
            return d.strftime("%Y-%m-%d")
        if step >= day or (d.hour == 0 and d.minute == 0):
            return d.strftime("%m-%d")
        return d.strftime("%H:%M")

    return ticks, label


def _fmt(v: float, step: float) -> str:
    decimals = max(0, -math.floor(math.log10(step)) + (1 if step / 10 ** math.floor(math.log10(step)) == 2.5 else 0))
    return f"{v:.{decimals}f}" if step < 1 else f"{v:,.0f}".replace(",", "\u2009")


GAP_FACTOR = 10.0
"""A line or band is broken where consecutive points lie more than this many times the series' median spacing
apart (a camera offline for months, or the night of a daytime-only camera): nothing was measured in between."""


def gap_breaks(times: Sequence[datetime], factor: float = GAP_FACTOR) -> set[int]:
    """Indices ``i`` of ``times`` (in time order) preceded by a gap longer than ``factor`` × the median spacing."""
    return _gap_breaks([t.timestamp() for t in times], factor)


def _gap_breaks(ts: Sequence[float], factor: float = GAP_FACTOR) -> set[int]:
    """:func:`gap_breaks` of POSIX times."""
    steps = [b - a for a, b in zip(ts, ts[1:], strict=False)]
    positive = sorted(d for d in steps if d > 0)
    if len(positive) < 2:
        return set()
    usual = positive[len(positive) // 2]
    return {i + 1 for i, d in enumerate(steps) if d > factor * usual}


def _band_runs(xs: list[float], lo: Sequence[float | None], hi: Sequence[float | None],
               breaks: set[int] = frozenset()) -> list[list[int]]:
    runs: list[list[int]] = []
    cur: list[int] = []
    for i in range(len(xs)):
        if cur and i in breaks:
            runs.append(cur)
            cur = []
        if lo[i] is not None and hi[i] is not None:
            cur.append(i)
        elif cur:
            runs.append(cur)
            cur = []
    if cur:
        runs.append(cur)
    return runs


def time_chart(series: Sequence[Series], *, title: str, unit: str = "", refs: Sequence[float] = (),
               refs_in_range: bool = False, chart_id: str = "chart", width: int = WIDTH, height: int = HEIGHT,
               css_class: str = "chart") -> Markup:
    """An SVG chart of ``series`` over time; ``refs`` are dashed horizontal lines (kept in range if ``refs_in_range``).

    ``width`` × ``height`` is the viewBox (the page scales it to its column): a narrower one keeps text readable on a
    phone.
    """
    stamps = [[t.timestamp() for t in s.times] for s in series]  # once per series (the chart's hot loop)
    breaks_of = [_gap_breaks(ts) for ts in stamps]
    all_t = [t for ts in stamps for t in ts]
    vals = [float(v) for s in series for v in s.values if v is not None and math.isfinite(v)]
    for s in series:
        for band in (s.lo, s.hi):
            if band is not None:
                vals += [float(v) for v in band if v is not None and math.isfinite(v)]
    label = f"{title} ({unit})" if unit else title
    head = (f'<svg class="{escape(css_class)}" id="{escape(chart_id)}" viewBox="0 0 {width} {height}" role="img" '
            f'aria-label="{escape(label)}" xmlns="http://www.w3.org/2000/svg"><title>{escape(label)}</title>')
    if not all_t or not vals:
        return Markup(head + f'<text class="empty" x="{width / 2}" y="{height / 2}" text-anchor="middle">'
                      f"{escape(title)}: no estimates yet</text></svg>")
    t0, t1 = min(all_t), max(all_t)
    if t1 - t0 < 600:
        t0, t1 = t0 - 1800, t1 + 1800
    if refs_in_range:
        vals += list(refs)
    v0, v1 = min(vals), max(vals)
    pad = (v1 - v0) * 0.08 or max(abs(v0) * 0.05, 1e-3)
    v0, v1 = v0 - pad, v1 + pad
    fr = _Frame(t0, t1, v0, v1, width, height)
    parts = [head, *_axes(fr, refs, width, height)]
    for s, ts, brk in zip(series, stamps, breaks_of, strict=True):  # bands, then lines and points
        parts += _band(s, ts, brk, fr)
    for s, ts, brk in zip(series, stamps, breaks_of, strict=True):
        parts += _line(s, ts, brk, fr)
    parts += _legend(series, label, width)
    parts.append("</svg>")
    return Markup("".join(parts))


def _axes(fr: _Frame, refs: Sequence[float], width: int, height: int) -> list[str]:
    """Grid lines with their ticks (values, and UTC times), the dashed reference lines in range and the frame."""
    parts = []
    yt = nice_ticks(fr.y0, fr.y1, 5)
    step = yt[1] - yt[0] if len(yt) > 1 else max(abs(yt[0]), 1.0)
    for v in yt:
        y = fr.y(v)
        parts.append(f'<line class="grid" x1="{LEFT}" x2="{width - RIGHT}" y1="{y:.1f}" y2="{y:.1f}"/>'
                     f'<text class="tick" x="{LEFT - 6}" y="{y + 4:.1f}" text-anchor="end">{escape(_fmt(v, step))}</text>')
    xt, tlabel = time_ticks(fr.t0, fr.t1, 6 if width >= 600 else 4)
    for t in xt:
        x = fr.x(t)
        parts.append(f'<line class="grid" x1="{x:.1f}" x2="{x:.1f}" y1="{TOP}" y2="{height - BOTTOM}"/>'
                     f'<text class="tick" x="{x:.1f}" y="{height - BOTTOM + 16}" text-anchor="middle">{tlabel(t)}</text>')
    parts.append(f'<text class="tick" x="{width - RIGHT}" y="{height - 2}" text-anchor="end">UTC</text>')
    for r in refs:
        if fr.y0 <= r <= fr.y1:
            y = fr.y(r)
            parts.append(f'<line class="ref" x1="{LEFT}" x2="{width - RIGHT}" y1="{y:.1f}" y2="{y:.1f}"/>')
    parts.append(f'<rect class="frame" x="{LEFT}" y="{TOP}" width="{width - LEFT - RIGHT}" height="{height - TOP - BOTTOM}"/>')
    return parts


def _band(s: Series, ts: list[float], breaks: set[int], fr: _Frame) -> list[str]:
    """A series' interval band: a polygon per run of points with both ends, a whisker for a lone point."""
    if s.lo is None or s.hi is None:
        return []
    parts = []
    xs = [fr.x(t) for t in ts]
    for run in _band_runs(xs, s.lo, s.hi, breaks):
        up = [f"{xs[i]:.1f},{fr.y(float(s.hi[i])):.1f}" for i in run]  # type: ignore[arg-type]
        down = [f"{xs[i]:.1f},{fr.y(float(s.lo[i])):.1f}" for i in reversed(run)]  # type: ignore[arg-type]
        if len(run) == 1:
            i = run[0]
            parts.append(f'<line class="{s.band_css} whisker" x1="{xs[i]:.1f}" x2="{xs[i]:.1f}" '
                         f'y1="{fr.y(float(s.lo[i])):.1f}" y2="{fr.y(float(s.hi[i])):.1f}"/>')  # type: ignore[arg-type]
        else:
            parts.append(f'<polygon class="{s.band_css}" points="{" ".join(up + down)}"/>')
    return parts


def _line(s: Series, ts: list[float], breaks: set[int], fr: _Frame) -> list[str]:
    """A series' line, broken at gaps and missing values, and its points (dots up to 400 points)."""
    parts = []
    pts, runs = [], [[]]
    for i, (t, v) in enumerate(zip(ts, s.values, strict=True)):
        if i in breaks and runs[-1]:
            runs.append([])
        if v is not None and math.isfinite(v):
            pts.append((fr.x(t), fr.y(float(v))))
            runs[-1].append(pts[-1])
    if not pts:
        return parts
    for run in runs:
        if len(run) > 1:
            parts.append(f'<polyline class="{s.css} line" points="{" ".join(f"{x:.1f},{y:.1f}" for x, y in run)}"/>')
        elif run and len(pts) > 400:  # an isolated point, where dots are not drawn
            parts.append(f'<circle class="{s.css} dot" cx="{run[0][0]:.1f}" cy="{run[0][1]:.1f}" r="2.2"/>')
    if len(pts) <= 400:
        parts.append("".join(f'<circle class="{s.css} dot" cx="{x:.1f}" cy="{y:.1f}" r="2.2"/>' for x, y in pts))
    return parts


def _legend(series: Sequence[Series], label: str, width: int) -> list[str]:
    """The chart's title (top left) and a key per series (top right)."""
    parts = [f'<text class="title" x="{LEFT}" y="16">{escape(label)}</text>']
    x = width - RIGHT
    for s in reversed(series):
        w = 18 + 7.2 * len(s.name)
        x -= w
        parts.append(f'<rect class="{s.css} key" x="{x:.1f}" y="8" width="10" height="10"/>'
                     f'<text class="legend" x="{x + 13:.1f}" y="17">{escape(s.name)}</text>')
    return parts
