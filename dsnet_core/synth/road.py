"""The road: a smooth curved centre line, Frenet coordinates (s along, d to the left), and the
ground layout across it (lanes, lane markings, parking strips, sidewalks, terrain)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

ROAD, PARKING, SIDEWALK, OTHER_GROUND, TERRAIN, LANE_MARKING = 40, 44, 48, 49, 72, 60
CURB_HEIGHT = 0.12
ROAD_EDGE, PARKING_END, LAWN_END, SIDEWALK_END = 0, 1, 2, 3  # rows of GroundLayout.edges
MARKING_WIDTH = 0.15
DASH_ON, DASH_PERIOD = 3.0, 9.0


@dataclass(frozen=True)
class Road:
    """Centre line sampled every ``ds`` metres of arc length.

    Attributes:
        s: ``(K,) float64`` arc length (metres); s = 0 is the ego's start.
        xy: ``(K, 2) float64`` world position (metres).
        heading: ``(K,) float64`` direction of travel (radians, counter-clockwise from +x).
    """

    s: np.ndarray
    xy: np.ndarray
    heading: np.ndarray

    @staticmethod
    def generate(rng: np.random.Generator, s_min: float, s_max: float, min_radius: float = 70.0) -> Road:
        """A random smooth road over ``[s_min, s_max]``, passing (0, 0) with heading 0 at s = 0."""
        ds = 0.5
        s = np.arange(s_min, s_max + ds, ds)
        kappa = np.zeros_like(s)
        for _ in range(3):
            wavelength = rng.uniform(120.0, 600.0)
            kappa += rng.normal() * np.sin(2 * np.pi * s / wavelength + rng.uniform(0, 2 * np.pi))
        peak = np.abs(kappa).max() or 1.0
        kappa *= rng.uniform(1.0 / 500.0, 1.0 / min_radius) / peak
        heading = np.concatenate([[0.0], np.cumsum(0.5 * (kappa[1:] + kappa[:-1]) * ds)])
        heading -= np.interp(0.0, s, heading)
        step = np.stack([np.cos(heading), np.sin(heading)], axis=1) * ds
        xy = np.concatenate([[[0.0, 0.0]], np.cumsum(0.5 * (step[1:] + step[:-1]), axis=0)])
        xy -= np.array([np.interp(0.0, s, xy[:, 0]), np.interp(0.0, s, xy[:, 1])])
        return Road(s, xy, heading)

    def pose_at(self, s: np.ndarray | float, d: np.ndarray | float = 0.0) -> tuple[np.ndarray, ...]:
        """World ``(x, y, heading)`` of Frenet points ``(s, d)``; straight extrapolation past the ends.

        Args:
            s: arc length (metres), any shape.
            d: lateral offset to the left (metres), broadcast with ``s``.
        """
        s, d = np.broadcast_arrays(np.asarray(s, np.float64), np.asarray(d, np.float64))
        sc = np.clip(s, self.s[0], self.s[-1])
        h = np.interp(sc, self.s, self.heading)
        x = np.interp(sc, self.s, self.xy[:, 0]) + (s - sc) * np.cos(h) - d * np.sin(h)
        y = np.interp(sc, self.s, self.xy[:, 1]) + (s - sc) * np.sin(h) + d * np.cos(h)
        return x, y, h

    def frenet_grid(
        self, x0: float, y0: float, nx: int, ny: int, res: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """Frenet coordinates of the cell centres of a world raster.

        Returns:
            ``s`` and ``d``, each ``(ny, nx) float32`` metres; cell (i, j) has centre
            ``(x0 + (j + 0.5) res, y0 + (i + 0.5) res)``.
        """
        gx = x0 + (np.arange(nx) + 0.5) * res
        gy = y0 + (np.arange(ny) + 0.5) * res
        px, py = np.meshgrid(gx, gy)
        pts = np.stack([px.ravel(), py.ravel()], axis=1)
        _, idx = cKDTree(self.xy).query(pts, workers=1)
        dp = pts - self.xy[idx]
        h = self.heading[idx]
        s = self.s[idx] + dp[:, 0] * np.cos(h) + dp[:, 1] * np.sin(h)
        d = -dp[:, 0] * np.sin(h) + dp[:, 1] * np.cos(h)
        return s.reshape(ny, nx).astype(np.float32), d.reshape(ny, nx).astype(np.float32)


@dataclass(frozen=True)
class GroundLayout:
    """Ground classes across the road, per side and per 1 m of arc length.

    Side 0 is the left (d > 0), side 1 the right (d < 0). Between the centre line and ``edges[:, 0]``
    lies road (at z = 0): ``lanes`` traffic lanes with dashed lines, then a bike lane behind a
    solid line; up to ``edges[:, 1]`` the kerbside strip of class
    ``classes[:, 0]`` (parking at z = 0, or raised grass/pavement); up to ``edges[:, 2]`` a grass strip
    (terrain, raised by the curb); up to ``edges[:, 3]`` sidewalk (raised); beyond it ``classes[:, 1]``
    (terrain or other-ground, raised). Empty strips have equal consecutive edges.

    Attributes:
        s0: arc length of bin 0 (metres).
        ds: bin length (metres).
        edges: ``(2, 4, n) float64`` |d| of road edge, parking end, grass end, sidewalk end (metres).
        classes: ``(2, 2, n) int32`` raw ids of the kerbside strip and of the ground beyond the sidewalk.
        lanes: lanes per side.
        lane_width: metres.
    """

    s0: float
    ds: float
    edges: np.ndarray
    classes: np.ndarray
    lanes: int
    lane_width: float

    def bin(self, s: float) -> int:
        return int(np.clip((s - self.s0) / self.ds, 0, self.edges.shape[2] - 1))

    def edge(self, side: int, which: int, s: float) -> float:
        """|d| of edge ``which`` (ROAD_EDGE ... SIDEWALK_END) on ``side`` at arc length ``s``."""
        return float(self.edges[side, which, self.bin(s)])
