"""Inline SVG charts: grouped horizontal bars and per-frame line charts (no scripts needed)."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

from .fmt import esc

PALETTE = ("#4e79a7", "#f28e2b", "#59a14f", "#e15759", "#b07aa1", "#76b7b2")
FONT = 'font-family="system-ui, sans-serif" font-size="11"'


def colour(i: int) -> str:
    return PALETTE[i % len(PALETTE)]


def _ok(v: float | None) -> bool:
    return v is not None and math.isfinite(v)


def hbars(
    labels: Sequence[str],
    values: Sequence[Sequence[float | None]],
    series: Sequence[str],
    vmax: float = 1.0,
    width: int = 520,
    bar: int = 9,
    fmt: Callable[[float], str] = lambda v: f"{100 * v:.1f}",
    chart_id: str = "",
) -> str:
    """Grouped horizontal bars: one group per label, one bar per series.

    Args:
        labels: ``(L,)`` group names.
        values: ``(S, L)`` values per series (None/NaN: no bar).
        series: ``(S,)`` series names (legend).
        vmax: value at the right end of the axis.
        fmt: value -> text shown after the bar.
    """
    left, right, top = 120, 52, 22
    group = bar * len(series) + 6
    height = top + group * len(labels) + 8
    plot = width - left - right
    out = [
        f'<svg class="chart" id="{esc(chart_id)}" viewBox="0 0 {width} {height}" width="{width}" '
        f'height="{height}" role="img" {FONT}>'
    ]
    for t in range(5):
        x = left + plot * t / 4
        out.append(f'<line x1="{x:.1f}" y1="{top - 4}" x2="{x:.1f}" y2="{height - 6}" class="grid"/>')
        out.append(
            f'<text x="{x:.1f}" y="{top - 8}" text-anchor="middle" class="axis">{fmt(vmax * t / 4)}</text>'
        )
    for li, label in enumerate(labels):
        y0 = top + li * group
        out.append(
            f'<text x="{left - 6}" y="{y0 + group / 2 + 1:.1f}" text-anchor="end" class="lbl">'
            f"{esc(label)}</text>"
        )
        for si, name in enumerate(series):
            v = values[si][li]
            if not _ok(v):
                continue
            w = max(0.0, min(1.0, v / vmax)) * plot if vmax > 0 else 0.0
            y = y0 + si * bar
            out.append(
                f'<rect x="{left}" y="{y}" width="{max(w, 0.8):.1f}" height="{bar - 1}" fill="{colour(si)}">'
                f"<title>{esc(name)} · {esc(label)}: {fmt(v)}</title></rect>"
            )
            out.append(f'<text x="{left + w + 3:.1f}" y="{y + bar - 2}" class="val">{fmt(v)}</text>')
    out.append("</svg>")
    return "".join(out)


def _path(xs: Sequence[float], ys: Sequence[float | None]) -> str:
    """A polyline path that breaks where y is missing."""
    parts, pen = [], False
    for x, y in zip(xs, ys, strict=True):
        if y is None:
            pen = False
            continue
        parts.append(f"{'L' if pen else 'M'}{x:.1f},{y:.1f}")
        pen = True
    return "".join(parts)


def frame_chart(
    index: Sequence[int],
    lines: Sequence[tuple[str, Sequence[float | None]]],
    points: Sequence[int],
    width: int = 980,
    height: int = 230,
    chart_id: str = "",
) -> str:
    """Per-frame PQ lines (0..100 %, upper panel) and points per frame (grey, lower panel).

    Args:
        index: ``(F,)`` frame indices (x axis).
        lines: ``(name, (F,) PQ or None)`` per run.
        points: ``(F,)`` points per frame (of the first run).
    """
    left, right, top, bottom, gap, strip = 44, 60, 12, 24, 14, 44
    plot_w = width - left - right
    plot_h = height - top - bottom - gap - strip
    lo, hi = (min(index), max(index)) if index else (0, 1)
    span = max(hi - lo, 1)

    def px(i: float) -> float:
        return left + plot_w * (i - lo) / span

    pmax = max(max(points, default=0), 1)
    out = [
        f'<svg class="chart frames" id="{esc(chart_id)}" viewBox="0 0 {width} {height}" width="{width}" '
        f'height="{height}" role="img" data-lo="{lo}" data-hi="{hi}" data-left="{left}" '
        f'data-plot="{plot_w}" {FONT}>'
    ]
    base = top + plot_h
    s_base = base + gap + strip
    if points:
        pts = " ".join(
            f"{px(i):.1f},{s_base - strip * p / pmax:.1f}" for i, p in zip(index, points, strict=True)
        )
        out.append(
            f'<polygon points="{px(index[0]):.1f},{s_base} {pts} {px(index[-1]):.1f},{s_base}" class="area"/>'
        )
    out.append(f'<text x="{left - 5}" y="{s_base - strip + 8}" text-anchor="end" class="axis">pts</text>')
    for t in (0, 1):
        y = s_base - strip * t
        out.append(f'<line x1="{left}" y1="{y:.1f}" x2="{left + plot_w}" y2="{y:.1f}" class="grid"/>')
        out.append(
            f'<text x="{left + plot_w + 5}" y="{y + 4:.1f}" class="axis pts">{_short(pmax * t)}</text>'
        )
    for t in range(5):
        y = base - plot_h * t / 4
        out.append(f'<line x1="{left}" y1="{y:.1f}" x2="{left + plot_w}" y2="{y:.1f}" class="grid"/>')
        out.append(f'<text x="{left - 5}" y="{y + 4:.1f}" text-anchor="end" class="axis">{25 * t}</text>')
    out.append(f'<text x="{left + plot_w + 5}" y="{top + 8}" class="axis">PQ %</text>')
    for i in ticks(lo, hi):
        out.append(f'<text x="{px(i):.1f}" y="{height - 6}" text-anchor="middle" class="axis">{i}</text>')
    for si, (name, pq) in enumerate(lines):
        ys = [None if not _ok(v) else base - plot_h * max(0.0, min(1.0, v)) for v in pq]
        out.append(
            f'<path d="{_path([px(i) for i in index], ys)}" fill="none" stroke="{colour(si)}" '
            f'stroke-width="1.6"><title>{esc(name)}</title></path>'
        )
    out.append(f'<line class="cursor" x1="-10" x2="-10" y1="{top}" y2="{s_base}"/>')
    out.append("</svg>")
    return "".join(out)


def ticks(lo: int, hi: int, most: int = 8) -> list[int]:
    """Integer ticks at a round step (1, 2 or 5 × 10^k) covering ``[lo, hi]``, at most ``most``."""
    span = max(hi - lo, 1)
    step = 1
    while span / step > most - 1:
        step = step * 5 // 2 if str(step)[0] == "2" else step * 2  # 1, 2, 5, 10, 20, 50, ...
    first = -(-lo // step) * step
    return list(range(first, hi + 1, step))


def _short(v: float) -> str:
    if v >= 1e6:
        return f"{v / 1e6:.1f}M"
    if v >= 1e3:
        return f"{v / 1e3:.0f}k"
    return f"{v:.0f}"
