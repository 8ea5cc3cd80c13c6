"""Find a LiDAR's optical centre (and the tilt of its spin axis) in its log's frame, from the
points alone (:func:`estimate_origin`).

Many logs are not in the sensor's frame: a vehicle frame puts the origin at the rear axle or on the
ground below it, metres from the sensor (PandaSet as unpacked here: the origin is ~0.33 m above the
road, the Pandar64 ~2.2 m). Seen from the wrong point, a beam's rays no longer share one elevation,
so the elevation histogram, sharp peaks from the true centre, smears into a ramp.

The centre is the point (and tilt) from which the elevation histogram of the points 4–80 m away is
sharpest: the Kullback–Leibler divergence of the fine histogram (0.02° bins) from its 0.6°
smoothed version (:func:`sharpness`). It is found in three steps, on at most ``max_points`` points:

1. **grid search** from the log's origin: cycles of grid scans over z (±4 m), then (x, pitch) and
   (y, roll) jointly (±3 m × ±5°: an offset along x and a pitch both tilt the elevations as
   cos(azimuth)), the spans narrowing 2.5× each cycle; along each axis the sharpness is smooth and
   single-peaked over ±1 m / ±2° around the centre;
2. **Nelder–Mead** on (x, y, z, roll, pitch) from there;
3. **beam least squares**: the points are given the nearest beam (histogram peaks), and centre and
   tilt are refined so that each beam's points share one elevation (robust loss), twice.

A log already in its sensor frame is left alone: one whose beams are exact (a simulated sensor, every
beam within 0.01°) without searching, others when the search sharpens the histogram by less than
25 %.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

from dsnet_core.sensor.beams import beam_peaks
from dsnet_core.sensor.card import SensorOrigin

EL_BIN = 0.02  # degrees, the sharpness histogram's bins
EL_SPAN = 60.0  # degrees: elevations beyond ±this are left out of the sharpness
COARSE = 0.6  # degrees: the smoothing the fine histogram is compared with
NEAR_H, FAR_H = 4.0, 80.0  # metres: horizontal distances the sharpness uses
GAIN = 1.25  # a centre is adopted when it sharpens the histogram at least this much


@dataclass(frozen=True)
class OriginFit:
    """What :func:`fit_origin` found.

    Attributes:
        origin: the sensor's centre and tilt in the log's frame (zeros: the log's origin kept).
        sharpness: the elevation histogram's sharpness from ``origin``.
        sharpness_at_log_origin: the same from the log's origin, untilted.
        moved: whether ``origin`` differs from the log's origin.
        exact: the beams were exact from the log's origin (no search run).
    """

    origin: SensorOrigin
    sharpness: float
    sharpness_at_log_origin: float
    moved: bool
    exact: bool = False


def rotation(roll_deg: float, pitch_deg: float) -> np.ndarray:
    """``(3, 3) float64`` ``Ry(pitch) · Rx(roll)``: the sensor's axes (columns) in the log's frame."""
    a, b = math.radians(roll_deg), math.radians(pitch_deg)
    ca, sa, cb, sb = math.cos(a), math.sin(a), math.cos(b), math.sin(b)
    rx = np.array([[1.0, 0.0, 0.0], [0.0, ca, -sa], [0.0, sa, ca]])
    ry = np.array([[cb, 0.0, sb], [0.0, 1.0, 0.0], [-sb, 0.0, cb]])
    return ry @ rx


def to_sensor_frame(xyz: np.ndarray, origin: SensorOrigin) -> np.ndarray:
    """``(N, 3) float64`` log points ``xyz`` ``(N, 3)`` in the sensor frame: ``Rᵀ (p − xyz_m)``."""
    return _apply(
        np.asarray(xyz, dtype=np.float64), np.array([*origin.xyz_m, origin.roll_deg, origin.pitch_deg])
    )


def _apply(pts: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``(N, 3)`` ``(pts − v[:3]) @ rotation(v[3], v[4])``, as three column updates (numpy's matmul
    of an (N, 3) by a (3, 3) array is several times slower)."""
    rot = rotation(float(v[3]), float(v[4]))
    d0, d1, d2 = pts[:, 0] - v[0], pts[:, 1] - v[1], pts[:, 2] - v[2]
    return np.stack([d0 * rot[0, k] + d1 * rot[1, k] + d2 * rot[2, k] for k in range(3)], axis=1)


def _params_origin(v: np.ndarray) -> SensorOrigin:
    return SensorOrigin(
        xyz_m=(round(float(v[0]), 4), round(float(v[1]), 4), round(float(v[2]), 4)),
        roll_deg=round(float(v[3]), 4),
        pitch_deg=round(float(v[4]), 4),
    )


def _elevations(pts: np.ndarray, v: np.ndarray, near: float = NEAR_H) -> np.ndarray:
    d = _apply(pts, v)
    h = np.hypot(d[:, 0], d[:, 1])
    keep = (h > near) & (h < FAR_H)
    return np.degrees(np.arctan2(d[keep, 2], h[keep]))


def _hist_sharpness(el: np.ndarray) -> float:
    from scipy.ndimage import gaussian_filter1d

    el = el[np.abs(el) < EL_SPAN]
    if el.size < 50:
        return 0.0
    n = int(2 * EL_SPAN / EL_BIN) + 1
    hist = np.bincount(((el + EL_SPAN) / EL_BIN).astype(np.int64), minlength=n).astype(np.float64)
    fine = gaussian_filter1d(hist, 1.0, mode="constant")
    coarse = gaussian_filter1d(hist, COARSE / EL_BIN, mode="constant")
    m = fine > 1e-12
    f, c = fine[m] / fine.sum(), np.maximum(coarse[m] / coarse.sum(), 1e-300)
    return float(np.sum(f * np.log(f / c)))


def sharpness(points: np.ndarray, origin: SensorOrigin | None = None) -> float:
    """How sharp the elevation histogram of ``points`` ``(N, ≥3)`` is seen from ``origin`` (default
    the log's origin): KL divergence (nats) of the 0.02° histogram from its 0.6° smoothing, over the
    points 4–80 m away horizontally. Larger is sharper; 0 for fewer than 50 such points."""
    o = origin or SensorOrigin()
    v = np.array([*o.xyz_m, o.roll_deg, o.pitch_deg], dtype=np.float64)
    return _hist_sharpness(_elevations(np.asarray(points, dtype=np.float64)[:, :3], v))


def _exact_beams(el: np.ndarray) -> bool:
    """Every beam one run of occupied 0.002° bins no wider than 0.01° (a simulated sensor)."""
    if el.size < 50:
        return False
    idx = np.unique(((el + 90.0) / 0.002).astype(np.int64))
    breaks = np.flatnonzero(np.diff(idx) > 1)
    starts = np.concatenate([[idx[0]], idx[breaks + 1]])
    ends = np.concatenate([idx[breaks], [idx[-1]]])
    return bool(np.all((ends - starts + 1) * 0.002 <= 0.01))


def _coordinate_search(pts: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, float]:
    """Cycles of grid scans over z alone, then (x, pitch) and (y, roll) together (an offset along x
    and a pitch both tilt the elevations as cos(azimuth), so they are searched jointly), the grid
    narrowing each cycle."""
    spans = np.array([3.0, 3.0, 4.0, 5.0, 5.0])  # x, y, z metres; roll, pitch degrees
    best = _hist_sharpness(_elevations(pts, v))
    for scale in (1.0, 0.4, 0.16, 0.064):
        for dims in ((2,), (0, 4), (1, 3)):
            ticks = [
                np.linspace(-spans[k] * scale, spans[k] * scale, 41 if len(dims) == 1 else 13) for k in dims
            ]
            top = v
            for d in itertools.product(*ticks):
                w = v.copy()
                w[list(dims)] += d
                s = _hist_sharpness(_elevations(pts, w))
                if s > best:
                    best, top = s, w
            v = top
    return v, best


def _nelder_mead(pts: np.ndarray, start: np.ndarray) -> tuple[np.ndarray, float]:
    from scipy.optimize import minimize

    steps = np.array([0.2, 0.2, 0.2, 0.5, 0.5])
    simplex = np.vstack([start, start + np.diag(steps)])
    res = minimize(
        lambda v: -_hist_sharpness(_elevations(pts, v)),
        start,
        method="Nelder-Mead",
        options={"initial_simplex": simplex, "xatol": 1e-3, "fatol": 1e-5, "maxiter": 500},
    )
    return np.asarray(res.x, dtype=np.float64), float(-res.fun)


def _beam_refine(pts: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Centre and tilt so that each beam's points share one elevation (robust least squares)."""
    from scipy.optimize import least_squares

    for _ in range(2):
        el = _elevations(pts, v, near=3.0)
        beams = beam_peaks(el)
        if beams.size < 2:
            return v
        neg = -beams
        gaps = np.diff(neg)
        half = np.minimum(np.concatenate([[np.inf], gaps]), np.concatenate([gaps, [np.inf]])) / 3
        d = _apply(pts, v)
        h = np.hypot(d[:, 0], d[:, 1])
        near = (h > 3.0) & (h < FAR_H)
        sel_pts = pts[near]
        e = -np.degrees(np.arctan2(d[near, 2], h[near]))
        k = np.clip(np.searchsorted((neg[1:] + neg[:-1]) / 2, e), 0, beams.size - 1)
        own = np.abs(e - neg[k]) <= half[k]
        sel_pts, k = sel_pts[own], k[own]
        if sel_pts.shape[0] < 100:
            return v
        if sel_pts.shape[0] > 20_000:
            pick = np.random.default_rng(1).choice(sel_pts.shape[0], 20_000, replace=False)
            sel_pts, k = sel_pts[pick], k[pick]
        counts = np.maximum(np.bincount(k, minlength=beams.size), 1)

        def residuals(p: np.ndarray, sel_pts=sel_pts, k=k, counts=counts) -> np.ndarray:
            q = _apply(sel_pts, p)
            el = np.degrees(np.arctan2(q[:, 2], np.hypot(q[:, 0], q[:, 1])))
            mean = np.bincount(k, weights=el, minlength=counts.size) / counts
            return el - mean[k]

        res = least_squares(
            residuals, v, loss="soft_l1", f_scale=0.05, x_scale=np.array([0.05, 0.05, 0.05, 0.2, 0.2])
        )
        v = np.asarray(res.x, dtype=np.float64)
    return v


def fit_origin(points: np.ndarray, max_points: int = 12_000, seed: int = 0) -> OriginFit:
    """Find the sensor's centre and tilt from ``points`` (see the module docstring).

    Args:
        points: ``(N, ≥3)`` float x, y, z (more columns ignored) of one or more scans, each in the
            log's frame (scans of one log may be stacked: the sensor sits at the same place in each).
            Rows at (0, 0, 0) (no-returns some formats write) are ignored.
        max_points: points used at most (a deterministic subsample).
        seed: the subsample's and RANSAC's seed.

    Returns:
        :class:`OriginFit`; ``fit.origin`` is zeros when the log's origin is kept.
    """
    xyz = np.asarray(points, dtype=np.float64)[:, :3]
    xyz = xyz[np.any(np.abs(xyz) > 1e-6, axis=1)]
    rng = np.random.default_rng(seed)
    if xyz.shape[0] > max_points:
        xyz = xyz[np.sort(rng.choice(xyz.shape[0], max_points, replace=False))]
    zero = np.zeros(5)
    el0 = _elevations(xyz, zero, near=2.0)
    s0 = _hist_sharpness(_elevations(xyz, zero))
    if _exact_beams(el0):
        return OriginFit(SensorOrigin(), s0, s0, moved=False, exact=True)
    v, _ = _coordinate_search(xyz, zero)
    best_v, best_s = _nelder_mead(xyz, v)
    if best_s <= max(GAIN * s0, 1e-9):  # (0 for a scan without 50 points 4–80 m away)
        return OriginFit(SensorOrigin(), s0, s0, moved=False)
    v = _beam_refine(xyz, best_v)
    s = _hist_sharpness(_elevations(xyz, v))
    if s < best_s:  # the refinement did not help (few beams, spread ones): keep the search's point
        v, s = best_v, best_s
    origin = _params_origin(v)
    return OriginFit(origin, s, s0, moved=True)


def estimate_origin(points: np.ndarray, max_points: int = 12_000) -> SensorOrigin:
    """The sensor's centre and tilt in the frame of ``points`` ``(N, ≥3)`` (float x, y, z first; one
    or more stacked scans of one log), as a :class:`~dsnet_core.sensor.card.SensorOrigin` (zeros: the
    log is in its sensor frame). A label path can call it on one scan (≈ 3 s on 12 000 points of a
    PandaSet scan on this project's shared CPU; ≈ 50 ms when the beams are already exact) and move
    the points into the sensor frame with :func:`to_sensor_frame`."""
    return fit_origin(points, max_points=max_points).origin
