"""Inline SVG charts over a sequence's frames: stacked class shares and value lines (no scripts).

Long sequences are drawn in at most :data:`MAX_BINS` bins of consecutive frames (the mean of each
bin), so a page stays small for thousands of frames.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from .fmt import esc
from .svg import FONT, ticks

MAX_BINS = 600


def _bins(index: Sequence[int], n: int = MAX_BINS) -> list[list[int]]:
    """Positions ``0..F-1`` grouped into at most ``n`` runs of consecutive positions."""
    f = len(index)
    size = max(1, math.ceil(f / n))
    return [list(range(i, min(i + size, f))) for i in range(0, f, size)]


def _mean(values: Sequence[float | None], pos: list[int]) -> float | None:
    vals = [values[p] for p in pos if values[p] is not None and math.isfinite(values[p])]
    return sum(vals) / len(vals) if vals else None


class _Frame:
    """The plot area of a chart over frames: x from frame index, y from a value in [0, vmax]."""

    def __init__(self, index: Sequence[int], width: int, height: int, vmax: float) -> None:
        self.left, self.right, self.top, self.bottom = 44, 70, 10, 22
        self.w = width - self.left - self.right
        self.h = height - self.top - self.bottom
        self.lo, self.hi = (min(index), max(index)) if index else (0, 1)
        self.vmax = vmax if vmax > 0 else 1.0
        self.width, self.height = width, height

    def x(self, i: float) -> float:
        return self.left + self.w * (i - self.lo) / max(self.hi - self.lo, 1)

    def y(self, v: float) -> float:
        return self.top + self.h * (1.0 - max(0.0, min(1.0, v / self.vmax)))

    def axes(self, unit: str, fmt) -> list[str]:
        out = []
        for t in range(5):
            v = self.vmax * t / 4
            y = self.y(v)
            out.append(
                f'<line x1="{self.left}" y1="{y:.1f}" x2="{self.left + self.w}" y2="{y:.1f}" class="grid"/>'
            )
            out.append(
                f'<text x="{self.left - 5}" y="{y + 4:.1f}" text-anchor="end" class="axis">{fmt(v)}</text>'
            )
        out.append(f'<text x="{self.left + self.w + 5}" y="{self.top + 8}" class="axis">{esc(unit)}</text>')
        for i in ticks(self.lo, self.hi):
            x = self.x(i)
            out.append(
                f'<text x="{x:.1f}" y="{self.height - 6}" text-anchor="middle" class="axis">{i}</text>'
            )
        return out


def _open(chart_id: str, width: int, height: int) -> str:
    return (
        f'<svg class="chart" id="{esc(chart_id)}" viewBox="0 0 {width} {height}" width="{width}" '
        f'height="{height}" role="img" {FONT}>'
    )


def stacked_shares(
    index: Sequence[int],
    bands: Sequence[tuple[str, str, Sequence[float]]],
    width: int = 980,
    height: int = 190,
    chart_id: str = "",
) -> str:
    """Each frame's class shares stacked to 100 %.

    Args:
        index: ``(F,)`` frame indices (x axis).
        bands: ``(name, colour, (F,) share in [0, 1])`` per class, bottom first.
    """
    fr = _Frame(index, width, height, 1.0)
    bins = _bins(index)
    xs = [fr.x(sum(index[p] for p in b) / len(b)) for b in bins]
    out = [_open(chart_id, width, height), *fr.axes("share %", lambda v: f"{100 * v:.0f}")]
    base = [0.0] * len(bins)
    for name, colour, shares in bands:
        top = [lo + (_mean(shares, b) or 0.0) for lo, b in zip(base, bins, strict=True)]
        upper = " ".join(f"{x:.1f},{fr.y(v):.1f}" for x, v in zip(xs, top, strict=True))
        lower = " ".join(f"{x:.1f},{fr.y(v):.1f}" for x, v in reversed(list(zip(xs, base, strict=True))))
        mean = sum(top) / len(top) - sum(base) / len(base) if bins else 0.0
        out.append(
            f'<polygon points="{upper} {lower}" fill="{esc(colour)}" stroke="none">'
            f"<title>{esc(name)}: {100 * mean:.1f} % of the points on average</title></polygon>"
        )
        base = top
    out.append("</svg>")
    return "".join(out)


def value_lines(
    index: Sequence[int],
    lines: Sequence[tuple[str, str, Sequence[float | None]]],
    vmax: float,
    unit: str,
    width: int = 980,
    height: int = 170,
    chart_id: str = "",
    percent: bool = True,
) -> str:
    """One line per series over the frames (gaps where a value is missing).

    Args:
        lines: ``(name, colour, (F,) value or None)``.
        vmax: value at the top of the axis.
        percent: show axis values as percentages.
    """
    fr = _Frame(index, width, height, vmax)
    bins = _bins(index)
    xs = [fr.x(sum(index[p] for p in b) / len(b)) for b in bins]
    digits = 1 if percent and vmax < 0.1 else 0  # a few per cent: ticks 0, 1.6, 3.3, ... not 0, 2, 3
    fmt = (lambda v: f"{100 * v:.{digits}f}") if percent else (lambda v: f"{v:.3g}")
    out = [_open(chart_id, width, height), *fr.axes(unit, fmt)]
    for name, colour, values in lines:
        parts, pen = [], False
        for x, b in zip(xs, bins, strict=True):
            v = _mean(values, b)
            if v is None:
                pen = False
                continue
            parts.append(f"{'L' if pen else 'M'}{x:.1f},{fr.y(v):.1f}")
            pen = True
        out.append(
            f'<path d="{"".join(parts)}" fill="none" stroke="{esc(colour)}" stroke-width="1.6">'
            f"<title>{esc(name)}</title></path>"
        )
    out.append("</svg>")
    return "".join(out)
