"""How alike two sensors are: two cards within tolerances (:func:`card_differences`), and two logs'
elevation histograms and points-per-range curves by the earth mover's distance (:func:`log_curves`,
:func:`emd`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dsnet_core.sensor.card import SensorCard

# what "the same card" means (the estimation tests' tolerances; docs/sensor.md)
TOLERANCES = {
    "elevation_deg": 0.1,
    "mount_height_m": 0.05,
    "mount_tilt_deg": 0.5,
    "ray_drop": 0.02,
    "returns_per_scan_rel": 0.03,
    "azimuth_steps_rel": 0.01,
    "fov_deg": 2.0,
    "range_noise_rel": 0.25,
    "max_range_rel": 0.05,
    "remission_quantile": 0.05,
}


def card_differences(a: SensorCard, b: SensorCard, tol: dict[str, float] | None = None) -> list[str]:
    """What differs between ``a`` and ``b`` beyond the tolerances (empty: the same sensor)."""
    t = {**TOLERANCES, **(tol or {})}
    out = []
    if a.beams != b.beams:
        return [f"beams {a.beams} vs {b.beams}"]
    el = float(np.max(np.abs(np.subtract(a.elevations_deg, b.elevations_deg))))
    if el > t["elevation_deg"]:
        out.append(f"elevations differ by up to {el:.3f}°")

    def rel(x: float, y: float) -> float:
        return abs(x - y) / max(abs(x), 1e-9)

    checks = [
        ("azimuth_steps", rel(a.azimuth_steps, b.azimuth_steps), t["azimuth_steps_rel"]),
        ("fov_deg", abs(a.fov_deg - b.fov_deg), t["fov_deg"]),
        ("mount_height_m", abs(a.mount_height_m - b.mount_height_m), t["mount_height_m"]),
        ("mount_pitch_deg", abs(a.mount_pitch_deg - b.mount_pitch_deg), t["mount_tilt_deg"]),
        ("mount_roll_deg", abs(a.mount_roll_deg - b.mount_roll_deg), t["mount_tilt_deg"]),
        ("ray_drop.rate", abs(a.ray_drop.rate - b.ray_drop.rate), t["ray_drop"]),
        ("returns_per_scan", rel(a.returns_per_scan, b.returns_per_scan), t["returns_per_scan_rel"]),
        ("range_noise_m", rel(a.range_noise_m, b.range_noise_m), t["range_noise_rel"]),
        ("max_range_m", rel(a.max_range_m, b.max_range_m), t["max_range_rel"]),
    ]
    q = float(np.max(np.abs(np.subtract(a.remission.quantiles, b.remission.quantiles))))
    checks.append(("remission.quantiles", q, t["remission_quantile"]))
    for key, diff, limit in checks:
        if diff > limit:
            out.append(f"{key}: {getattr(a, key, '')} vs {getattr(b, key, '')} (off by {diff:.4g} > {limit})")
    return out


@dataclass(frozen=True)
class LogCurves:
    """Per-log distributions (all ``float64``).

    Attributes:
        el_centres: ``(E,)`` elevation bin centres (degrees); elevation: ``(E,)`` share of points.
        range_centres: ``(R,)`` range bin centres (metres); per_range: ``(R,)`` points per scan.
    """

    el_centres: np.ndarray
    elevation: np.ndarray
    range_centres: np.ndarray
    per_range: np.ndarray


EL_EDGES = np.arange(-40.0, 40.0 + 1e-9, 0.1)
RANGE_EDGES = np.arange(0.0, 150.0 + 1e-9, 1.0)


def log_curves(scans: list[np.ndarray]) -> LogCurves:
    """Elevation histogram and points-per-range curve of ``scans`` (each ``(N, ≥3)``)."""
    el_hist = np.zeros(EL_EDGES.size - 1)
    r_hist = np.zeros(RANGE_EDGES.size - 1)
    for s in scans:
        xyz = np.asarray(s[:, :3], dtype=np.float64)
        el = np.degrees(np.arctan2(xyz[:, 2], np.hypot(xyz[:, 0], xyz[:, 1])))
        el_hist += np.histogram(el, EL_EDGES)[0]
        r_hist += np.histogram(np.linalg.norm(xyz, axis=1), RANGE_EDGES)[0]
    return LogCurves(
        (EL_EDGES[1:] + EL_EDGES[:-1]) / 2,
        el_hist / max(el_hist.sum(), 1.0),
        (RANGE_EDGES[1:] + RANGE_EDGES[:-1]) / 2,
        r_hist / max(len(scans), 1),
    )


def emd(p: np.ndarray, q: np.ndarray, width: float) -> float:
    """Earth mover's distance between two histograms on the same bins of ``width`` (each normalised
    to sum 1 first), in the bins' unit."""
    p = np.asarray(p, dtype=np.float64) / max(float(np.sum(p)), 1e-12)
    q = np.asarray(q, dtype=np.float64) / max(float(np.sum(q)), 1e-12)
    return float(np.abs(np.cumsum(p - q)).sum() * width)
