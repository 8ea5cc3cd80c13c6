"""LiDAR mixing between a target and a source scan: LaserMix-style inclination bands and
PolarMix-style azimuth sectors.

A mix of scans ``a`` and ``b`` gives two scans that together hold every point of both exactly once,
each point with its own label, instance, centre and weight (points and labels stay paired, counts
are unchanged): ``a``'s points in the chosen bands (or outside the sector) with ``b``'s other
points, and the complement. Angles are taken in each scan's own sensor frame, so a mixed scan
keeps the geometry a spinning sensor would see: rings of the target at some inclinations, of the
source at the others (LaserMix, Kong et al. CVPR 2023), or one azimuth sector swapped (PolarMix,
Xiao et al. NeurIPS 2022, scene-level swapping).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from dsnet_core.errors import ConfigError

MIX_MODES = ("both", "laser", "polar", "none")
"""``both`` draws laser or polar per pair; ``none`` keeps the scans apart."""


@dataclass(frozen=True)
class Cloud:
    """One training scan with everything per point.

    Attributes:
        points: ``(N, 4) float32`` x, y, z (metres, sensor frame), remission.
        sem: ``(N,) int64`` train ids (0 = ignored).
        inst: ``(N,) int64`` instance keys (0 = no instance target).
        centre: ``(N, 3) float32`` the instance's centre for points with ``inst > 0`` (else 0),
            computed on the whole scan before any mixing.
        weight: ``(N,) float32`` loss weight.
    """

    points: np.ndarray
    sem: np.ndarray
    inst: np.ndarray
    centre: np.ndarray
    weight: np.ndarray

    def __len__(self) -> int:
        return int(self.points.shape[0])

    def take(self, mask: np.ndarray) -> Cloud:
        return Cloud(self.points[mask], self.sem[mask], self.inst[mask], self.centre[mask], self.weight[mask])


def concat(parts: list[Cloud]) -> Cloud:
    """Points of ``parts`` in order, attributes with them."""
    return Cloud(
        *(
            np.concatenate([getattr(p, f) for p in parts])
            for f in ("points", "sem", "inst", "centre", "weight")
        )
    )


def inclination(points: np.ndarray) -> np.ndarray:
    """``(N,) float64`` elevation angle of each point seen from the sensor (radians)."""
    p = np.asarray(points, np.float64)
    return np.arctan2(p[:, 2], np.hypot(p[:, 0], p[:, 1]))


def azimuth(points: np.ndarray) -> np.ndarray:
    """``(N,) float64`` azimuth in [0, 2π) (radians, counter-clockwise from +x)."""
    p = np.asarray(points, np.float64)
    return np.mod(np.arctan2(p[:, 1], p[:, 0]), 2 * math.pi)


def laser_mix(a: Cloud, b: Cloud, bands: int) -> tuple[Cloud, Cloud]:
    """Split the inclination range both scans cover into ``bands`` equal bands; the first scan
    takes ``a``'s points in the even bands and ``b``'s in the odd ones, the second the rest.

    Raises:
        ConfigError: fewer than two bands.
    """
    ea, eb = laser_masks(a.points, b.points, bands)
    return concat([a.take(ea), b.take(~eb)]), concat([b.take(eb), a.take(~ea)])


def laser_masks(a: np.ndarray, b: np.ndarray, bands: int) -> tuple[np.ndarray, np.ndarray]:
    """``(N_a,) bool, (N_b,) bool``: the points of ``a`` and of ``b`` (``(N, ≥3)`` arrays) in the
    even ones of ``bands`` equal inclination bands over the range both cover (:func:`laser_mix`).

    Raises:
        ConfigError: fewer than two bands.
    """
    if bands < 2:
        raise ConfigError(f"laser mixing needs at least 2 inclination bands, got {bands}")
    ia, ib = inclination(a), inclination(b)
    both = np.concatenate([ia, ib])
    lo, hi = (float(both.min()), float(both.max())) if both.size else (0.0, 1.0)
    span = max(hi - lo, 1e-9)

    def even(incl: np.ndarray) -> np.ndarray:
        band = np.clip(((incl - lo) / span * bands).astype(np.int64), 0, bands - 1)
        return band % 2 == 0

    return even(ia), even(ib)


def polar_mix(a: Cloud, b: Cloud, start: float, width: float) -> tuple[Cloud, Cloud]:
    """Swap the azimuth sector ``[start, start + width)`` (radians, wrapping at 2π): the first scan
    is ``a`` with ``b``'s points in the sector, the second ``b`` with ``a``'s."""
    sa, sb = sector_mask(a.points, start, width), sector_mask(b.points, start, width)
    return concat([a.take(~sa), b.take(sb)]), concat([b.take(~sb), a.take(sa)])


def sector_mask(points: np.ndarray, start: float, width: float) -> np.ndarray:
    """``(N,) bool``: the points of ``points`` (``(N, ≥3)``) in the azimuth sector
    ``[start, start + width)`` (radians, wrapping at 2π)."""
    return np.mod(azimuth(points) - start, 2 * math.pi) < width


def mix_pair(
    a: Cloud,
    b: Cloud,
    mode: str,
    rng: np.random.Generator,
    bands: tuple[int, int] = (2, 6),
    sector_deg: tuple[float, float] = (45.0, 180.0),
) -> tuple[Cloud, Cloud, str]:
    """Mix ``a`` and ``b`` as ``mode`` says (:data:`MIX_MODES`), drawing the bands or the sector
    from ``rng``; returns the two scans and the mix used (``laser``, ``polar`` or ``none``).

    Raises:
        ConfigError: an unknown mode.
    """
    if mode not in MIX_MODES:
        raise ConfigError(f"unknown mixing {mode!r}; choose one of {', '.join(MIX_MODES)}")
    if mode == "both":
        mode = ("laser", "polar")[int(rng.integers(2))]
    if mode == "laser":
        return (*laser_mix(a, b, int(rng.integers(bands[0], bands[1] + 1))), mode)
    if mode == "polar":
        start = float(rng.uniform(0.0, 2 * math.pi))
        width = math.radians(float(rng.uniform(*sector_deg)))
        return (*polar_mix(a, b, start, width), mode)
    return a, b, "none"
