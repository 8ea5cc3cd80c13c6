"""How numbers are shown: one function per kind, used by the page and by its tests."""

from __future__ import annotations

import html
import math


def score(v: float | None) -> str:
    """A score in [0, 1] shown as a percentage with one decimal (``0.7345`` -> ``73.5``)."""
    if v is None or not math.isfinite(v):
        return "–"
    return f"{100.0 * v:.1f}"


def delta(v: float | None, base: float | None) -> str:
    """A signed difference of two scores in percentage points (``+1.2``)."""
    if v is None or base is None or not (math.isfinite(v) and math.isfinite(base)):
        return "–"
    return f"{100.0 * (v - base):+.1f}"


def count(v: int | None) -> str:
    """An integer with thin thousands separators."""
    return "–" if v is None else f"{int(v):,}".replace(",", "\u2009")


def seconds(v: float | None) -> str:
    if v is None or not math.isfinite(v):
        return "–"
    return f"{v:.2f}" if v < 100 else f"{v:.0f}"


def rate(v: float | None) -> str:
    """Items or points per second, 3 significant digits with k/M suffixes."""
    if v is None or not math.isfinite(v):
        return "–"
    for div, suffix in ((1e6, "M"), (1e3, "k")):
        if abs(v) >= div:
            return f"{v / div:.3g}{suffix}"
    return f"{v:.3g}"


def esc(s: object) -> str:
    return html.escape(str(s), quote=True)


def cell(text: str, key: str | None = None, value: object = None, cls: str = "") -> str:
    """A ``<td>``; ``key``/``value`` go to ``data-k``/``data-v`` so tests can check what is shown."""
    attrs = f' class="{cls}"' if cls else ""
    if key is not None:
        attrs += f' data-k="{esc(key)}" data-v="{esc("" if value is None else repr(value))}"'
    return f"<td{attrs}>{esc(text)}</td>"
