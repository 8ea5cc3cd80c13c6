"""Beam elevations from points' elevation angles: the peaks of their histogram (shared by the
estimate and the sensor-centre search)."""

from __future__ import annotations

import numpy as np

EL_BIN = 0.002  # degrees, elevation histogram resolution


def beam_peaks(el: np.ndarray) -> np.ndarray:
    """``(B,) float64`` beam elevations (degrees, top first) from points' elevations ``(N,)``."""
    if el.size == 0:
        return np.zeros(0)
    idx = np.clip(((el + 90.0) / EL_BIN).astype(np.int64), 0, int(180 / EL_BIN))
    hist = np.bincount(idx, minlength=int(180 / EL_BIN) + 1).astype(np.float64)
    occupied = np.flatnonzero(hist)
    # a simulated sensor: every beam is one or two adjacent bins (runs of occupied bins stay narrow)
    breaks = np.flatnonzero(np.diff(occupied) > 1)
    starts = np.concatenate([[occupied[0]], occupied[breaks + 1]])
    ends = np.concatenate([occupied[breaks], [occupied[-1]]])
    widths = (ends - starts + 1) * EL_BIN
    mass = np.add.reduceat(hist[occupied], np.concatenate([[0], breaks + 1]))
    if np.all(widths <= 0.01) or mass[widths <= 0.01].sum() >= 0.999 * mass.sum():
        keep = (widths <= 0.01) & (mass >= 3)
        order = np.argsort(idx)
        sorted_el, sorted_idx = el[order], idx[order]
        out = []
        for a, b in zip(starts[keep], ends[keep], strict=True):
            lo, hi = np.searchsorted(sorted_idx, a), np.searchsorted(sorted_idx, b, side="right")
            out.append(float(np.median(sorted_el[lo:hi])))
        return np.sort(np.asarray(out))[::-1]
    return _spread_beams(el, hist)


def _spread_beams(el: np.ndarray, hist: np.ndarray) -> np.ndarray:
    """Beams of a real sensor: peaks of the smoothed histogram with prominence ≥ half their height."""
    from scipy.ndimage import gaussian_filter1d
    from scipy.signal import find_peaks

    smooth = gaussian_filter1d(hist, sigma=0.02 / EL_BIN, mode="constant")
    peaks, props = find_peaks(smooth, prominence=0.0)
    strong = props["prominences"] >= 0.5 * smooth[peaks]
    peaks = peaks[strong]
    mass_floor = max(20.0, 0.002 * np.median(smooth[peaks]) * 10) if peaks.size else 0.0
    peaks = peaks[smooth[peaks] * (0.02 / EL_BIN) * 2.5 >= mass_floor]
    centres = peaks * EL_BIN - 90.0 + 0.5 * EL_BIN
    if centres.size == 0:
        return centres
    # refine: median of the points within ± a third of the spacing to the nearest neighbour beam
    gaps = np.diff(centres)
    half = np.minimum(np.concatenate([[np.inf], gaps]), np.concatenate([gaps, [np.inf]])) / 3
    half = np.minimum(half, 0.3)
    sorted_el = np.sort(el)
    out = []
    for c, h in zip(centres, half, strict=True):
        lo, hi = np.searchsorted(sorted_el, c - h), np.searchsorted(sorted_el, c + h)
        out.append(float(np.median(sorted_el[lo:hi])) if hi > lo else float(c))
    return np.sort(np.asarray(out))[::-1]
