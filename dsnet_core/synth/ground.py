"""Raster ground for the street styles: a fine world raster of ground classes and raised (kerbed)
cells over a smooth height surface (grade along the street, crowned carriageway).

The classic street keeps its analytic flat ground (:func:`raycast.ground_hits_frenet`); styled
streets paint their ground here, so junctions, parking lots and driveways need no special kernel.
A ray meets the surface ``h(x, y) + kerb · raised(x, y)``: it is sphere-traced against the raised
level, then the low level, using the surface's largest gradient as a Lipschitz bound.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba as nb
import numpy as np
from scipy.ndimage import map_coordinates

from dsnet_core.synth.road import TERRAIN, Road

FINE_RES = 0.2  # metres per class cell
HEIGHT_RES = 1.0  # metres per height cell (the surface is smooth)


@dataclass(frozen=True)
class RasterGround:
    """A painted ground.

    Attributes:
        origin: ``(x0, y0)`` world corner of both rasters (metres).
        cls: ``(ny, nx) uint8`` raw SemanticKITTI class of each ``FINE_RES`` cell.
        raised: ``(ny, nx) uint8`` 1 where the cell stands ``kerb`` above the surface.
        height: ``(my, mx) float64`` smooth surface height at ``HEIGHT_RES`` cell centres (metres).
        kerb: kerb height (metres; 0 = flush everywhere).
        grade: bound on ``|∇height|`` (dimensionless).
    """

    origin: tuple[float, float]
    cls: np.ndarray
    raised: np.ndarray
    height: np.ndarray
    kerb: float
    grade: float

    def meta(self) -> np.ndarray:
        """``[x0, y0, fine res, height res, kerb, grade, max height]`` for the kernel."""
        x0, y0 = self.origin
        return np.array(
            [x0, y0, FINE_RES, HEIGHT_RES, self.kerb, self.grade, float(self.height.max())], np.float64
        )

    def surface(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Smooth surface height at world ``(x, y)`` (metres, any shape; no kerbs)."""
        x0, y0 = self.origin
        fi = (np.asarray(y) - y0) / HEIGHT_RES - 0.5
        fj = (np.asarray(x) - x0) / HEIGHT_RES - 0.5
        return map_coordinates(self.height, [np.ravel(fi), np.ravel(fj)], order=1, mode="nearest").reshape(
            np.shape(x)
        )

    def cell(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Fine-raster indices ``(i, j)`` of world points (clipped to the raster)."""
        x0, y0 = self.origin
        i = np.clip(((np.asarray(y) - y0) / FINE_RES).astype(np.int64), 0, self.cls.shape[0] - 1)
        j = np.clip(((np.asarray(x) - x0) / FINE_RES).astype(np.int64), 0, self.cls.shape[1] - 1)
        return i, j

    def height_at(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Top of the ground (surface plus kerb where raised) at world ``(x, y)``, metres."""
        i, j = self.cell(x, y)
        return self.surface(x, y) + self.kerb * self.raised[i, j]

    def kernel_args(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        return self.cls, self.raised, self.height, self.meta()


@dataclass(frozen=True)
class Canvas:
    """World and Frenet coordinates of every fine cell, for painting.

    Attributes:
        origin: world corner (metres).
        x, y: ``(ny, nx) float32`` world cell centres.
        s, d: ``(ny, nx) float32`` Frenet coordinates of the cell centres along the main road.
        hs, hd: ``(my, mx) float32`` Frenet coordinates of the height-cell centres.
    """

    origin: tuple[float, float]
    x: np.ndarray
    y: np.ndarray
    s: np.ndarray
    d: np.ndarray
    hs: np.ndarray
    hd: np.ndarray


def make_canvas(road: Road, lo: np.ndarray, hi: np.ndarray) -> Canvas:
    """A canvas over the world box ``[lo, hi]`` (``(2,)`` metres)."""
    mx, my = (np.ceil((hi - lo) / HEIGHT_RES).astype(int) + 1).tolist()
    hs, hd = road.frenet_grid(float(lo[0]), float(lo[1]), mx, my, HEIGHT_RES)
    scale = round(HEIGHT_RES / FINE_RES)
    nx, ny = mx * scale, my * scale
    gx = float(lo[0]) + (np.arange(nx, dtype=np.float32) + 0.5) * FINE_RES
    gy = float(lo[1]) + (np.arange(ny, dtype=np.float32) + 0.5) * FINE_RES
    fi = ((np.arange(ny) + 0.5) * FINE_RES / HEIGHT_RES - 0.5).astype(np.float32)
    fj = ((np.arange(nx) + 0.5) * FINE_RES / HEIGHT_RES - 0.5).astype(np.float32)
    ii, jj = np.meshgrid(fi, fj, indexing="ij")
    s = map_coordinates(hs, [ii, jj], order=1, mode="nearest")
    d = map_coordinates(hd, [ii, jj], order=1, mode="nearest")
    x, y = np.meshgrid(gx, gy)
    return Canvas((float(lo[0]), float(lo[1])), x, y, s, d, hs, hd)


def grade_profile(rng: np.random.Generator, hilly: float) -> tuple[float, float, float, float]:
    """Parameters ``(base grade, amplitude, wavelength m, phase)`` of a street's grade along s;
    ``hilly`` in [0, 1] scales the grade (0: flat)."""
    return (
        float(rng.uniform(-0.04, 0.04) * hilly),
        float(rng.uniform(0.0, 0.03) * hilly),
        float(rng.uniform(150.0, 400.0)),
        float(rng.uniform(0.0, 2 * np.pi)),
    )


def street_height(
    s: np.ndarray, d: np.ndarray, grade: tuple[float, float, float, float], crown: float, half_width: float
) -> np.ndarray:
    """Surface height (metres) at Frenet ``(s, d)``: the integral of the grade along s (0 at s = 0)
    plus a parabolic crown falling ``crown`` (metres) from the centre line to ``half_width``."""
    g0, amp, wavelength, phase = grade
    w = 2 * np.pi / wavelength
    z = g0 * s - amp / w * (np.cos(w * s + phase) - np.cos(phase))
    q = np.minimum(np.abs(d), half_width) / max(half_width, 1e-6)
    return z - crown * q * q


def finish(
    canvas: Canvas, cls: np.ndarray, raised: np.ndarray, height: np.ndarray, kerb: float
) -> RasterGround:
    """Wrap painted rasters; the gradient bound is measured on the height raster."""
    gy, gx = np.gradient(height, HEIGHT_RES)
    grade = float(np.hypot(gx, gy).max()) * 1.15 + 0.01
    return RasterGround(
        canvas.origin,
        np.ascontiguousarray(cls, np.uint8),
        np.ascontiguousarray(raised if kerb > 0 else np.zeros_like(raised), np.uint8),
        np.ascontiguousarray(height, np.float64),
        float(kerb),
        grade,
    )


# -- kernels ------------------------------------------------------------------------------------
@nb.njit(cache=True)
def _height(x, y, height, meta):
    """Bilinear surface height at world (x, y), clamped at the raster's border."""
    my, mx = height.shape
    fx = min(max((x - meta[0]) / meta[3] - 0.5, 0.0), mx - 1.000001)
    fy = min(max((y - meta[1]) / meta[3] - 0.5, 0.0), my - 1.000001)
    j = int(fx)
    i = int(fy)
    ax = fx - j
    ay = fy - i
    return (1 - ay) * ((1 - ax) * height[i, j] + ax * height[i, j + 1]) + ay * (
        (1 - ax) * height[i + 1, j] + ax * height[i + 1, j + 1]
    )


@nb.njit(cache=True)
def _cell(x, y, cls, raised, meta):
    """(raw class, raised) of the fine cell at world (x, y); terrain, raised outside the raster."""
    ny, nx = cls.shape
    j = math.floor((x - meta[0]) / meta[2])
    i = math.floor((y - meta[1]) / meta[2])
    if i < 0 or j < 0 or i >= ny or j >= nx:
        return TERRAIN, True
    return cls[i, j], raised[i, j] != 0


@nb.njit(cache=True)
def _trace(ox, oy, oz, dx, dy, dz, height, meta, level, t_max):
    """First t where the ray meets ``surface + level`` (inf: none before ``t_max``)."""
    grade = meta[5]
    rate = grade - dz  # f(t) = z(t) - surface - level falls at most this fast
    if rate <= 1e-9:
        return math.inf
    t = 0.0
    if dz < 0.0:
        t = max(0.0, (oz - meta[6] - level) / -dz)
    f = oz + t * dz - _height(ox + t * dx, oy + t * dy, height, meta) - level
    if f <= 0.0:
        return t
    t_prev, f_prev = t, f
    for _ in range(80):
        if f < 0.02:
            break
        t_prev, f_prev = t, f
        t += f / rate
        if t > t_max:
            return math.inf
        f = oz + t * dz - _height(ox + t * dx, oy + t * dy, height, meta) - level
    for _ in range(3):  # secant refinement: the surface is nearly planar at this scale
        if abs(f_prev - f) < 1e-12 or abs(f) < 1e-4:
            break
        t_new = t - f * (t - t_prev) / (f - f_prev)
        t_prev, f_prev = t, f
        t = t_new
        f = oz + t * dz - _height(ox + t * dx, oy + t * dy, height, meta) - level
    return t if t <= t_max else math.inf


@nb.njit(cache=True)
def ground_hits_raster(origin, rot, dirs, cls, raised, height, meta, t_max):
    """Ground hit of every sensor-frame ray ``dirs (R, 3)`` from ``origin`` rotated by ``rot``.

    Returns:
        t ``(R,)`` distance (inf: none within ``t_max``), raw class ``(R,) int32``, |cos incidence|
        ``(R,)`` (kerb faces are vertical).
    """
    nr = dirs.shape[0]
    out_t = np.full(nr, math.inf)
    out_cls = np.zeros(nr, np.int32)
    out_cos = np.zeros(nr)
    ox, oy, oz = origin[0], origin[1], origin[2]
    kerb = meta[4]
    for r in range(nr):
        sx, sy, sz = dirs[r, 0], dirs[r, 1], dirs[r, 2]
        dx = rot[0, 0] * sx + rot[0, 1] * sy + rot[0, 2] * sz
        dy = rot[1, 0] * sx + rot[1, 1] * sy + rot[1, 2] * sz
        dz = rot[2, 0] * sx + rot[2, 1] * sy + rot[2, 2] * sz
        if kerb > 0.0:
            t1 = _trace(ox, oy, oz, dx, dy, dz, height, meta, kerb, t_max)
            if t1 == math.inf:
                continue
            c1, up1 = _cell(ox + t1 * dx, oy + t1 * dy, cls, raised, meta)
            if up1:
                out_t[r], out_cls[r], out_cos[r] = t1, c1, abs(dz)
                continue
        t0 = _trace(ox, oy, oz, dx, dy, dz, height, meta, 0.0, t_max)
        if t0 == math.inf:
            continue
        c0, up0 = _cell(ox + t0 * dx, oy + t0 * dy, cls, raised, meta)
        out_t[r], out_cls[r] = t0, c0
        out_cos[r] = abs(dz) if not up0 else math.sqrt(max(0.0, 1.0 - dz * dz))  # a kerb face
    return out_t, out_cls, out_cos
