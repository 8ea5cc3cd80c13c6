"""Ray casting kernels (numba, compiled once and cached on disk).

Rays are cast in world coordinates against the ground (road at z = 0, lawns, sidewalks and beyond
raised by the curb, classes looked up in Frenet coordinates) and against every primitive; the nearest
hit wins. Primitives are culled per ray by a world-azimuth bin table and an elevation interval, and
visited in order of their nearest possible distance so the search stops as soon as nothing closer
can exist.

Argument bundles (tuples, so the kernels keep short signatures):
    prims  = (kind, center, yaw, half, semantic, instance, reflectivity)  -- see PrimitiveSet
    cull   = (near, el_lo, el_hi, start, items)                            -- from bin_primitives
    ground = (s raster, d raster, meta, edges, classes, lanes) with
             meta = [x0, y0, res, s0, ds, lane width]                      -- see GroundLayout
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from dsnet_core.synth.road import (
    CURB_HEIGHT,
    DASH_ON,
    DASH_PERIOD,
    LANE_MARKING,
    MARKING_WIDTH,
    PARKING,
    ROAD,
    SIDEWALK,
    TERRAIN,
)

VEGETATION = 70
FOLIAGE_DEPTH = 0.3  # mean penetration of a ray into foliage (metres)
_GROUND_REFL = {ROAD: 0.22, LANE_MARKING: 0.75, PARKING: 0.26, SIDEWALK: 0.33, 49: 0.28, TERRAIN: 0.42}
GROUND_REFLECTIVITY = np.zeros(256, dtype=np.float64)
for _k, _v in _GROUND_REFL.items():
    GROUND_REFLECTIVITY[_k] = _v


@nb.njit(cache=True)
def _frenet(x, y, g):
    """Bilinear lookup of Frenet (s, d) at world (x, y); NaN outside the raster."""
    grid_s, grid_d, meta = g[0], g[1], g[2]
    ny, nx = grid_s.shape
    fx = (x - meta[0]) / meta[2] - 0.5
    fy = (y - meta[1]) / meta[2] - 0.5
    if fx < 0.0 or fy < 0.0 or fx >= nx - 1 or fy >= ny - 1:
        return math.nan, math.nan
    j = int(fx)
    i = int(fy)
    ax = fx - j
    ay = fy - i
    w00, w01, w10, w11 = (1 - ay) * (1 - ax), (1 - ay) * ax, ay * (1 - ax), ay * ax
    s = w00 * grid_s[i, j] + w01 * grid_s[i, j + 1] + w10 * grid_s[i + 1, j] + w11 * grid_s[i + 1, j + 1]
    d = w00 * grid_d[i, j] + w01 * grid_d[i, j + 1] + w10 * grid_d[i + 1, j] + w11 * grid_d[i + 1, j + 1]
    return s, d


@nb.njit(cache=True)
def _zone(s, d, g):
    """(raw class, raised) of the ground at Frenet point (s, d)."""
    if math.isnan(s):
        return TERRAIN, True
    meta, edges, classes, lanes = g[2], g[3], g[4], g[5]
    side = 0 if d >= 0.0 else 1
    ad = abs(d)
    k = min(max(int((s - meta[3]) / meta[4]), 0), edges.shape[2] - 1)
    if ad < edges[side, 0, k]:
        hw = 0.5 * MARKING_WIDTH
        dashed = (s % DASH_PERIOD) < DASH_ON
        if ad < hw and (dashed or lanes > 1):
            return LANE_MARKING, False
        for m in range(1, lanes):
            if abs(ad - m * meta[5]) < hw and dashed:
                return LANE_MARKING, False
        if abs(ad - lanes * meta[5]) < hw:  # the solid line between traffic and bike lane
            return LANE_MARKING, False
        return ROAD, False
    if ad < edges[side, 1, k]:
        strip = classes[side, 0, k]
        return strip, strip != PARKING
    if ad < edges[side, 2, k]:
        return TERRAIN, True
    if ad < edges[side, 3, k]:
        return SIDEWALK, True
    return classes[side, 1, k], True


@nb.njit(cache=True)
def _ground(ox, oy, oz, dx, dy, dz, g):
    """(t, raw class, |cos incidence|) of the ground hit; t = inf when the ray does not descend."""
    if dz > -1e-9:
        return math.inf, 0, 0.0
    t1 = (CURB_HEIGHT - oz) / dz
    s, d = _frenet(ox + t1 * dx, oy + t1 * dy, g)
    cls, raised = _zone(s, d, g)
    if raised:
        return t1, cls, -dz
    t0 = -oz / dz
    s, d = _frenet(ox + t0 * dx, oy + t0 * dy, g)
    cls0, raised0 = _zone(s, d, g)
    if not raised0:
        return t0, cls0, -dz
    return t0, cls0, math.sqrt(max(0.0, 1.0 - dz * dz))  # the curb face


@nb.njit(cache=True)
def _intersect(kind, px, py, pz, dx, dy, dz, hx, hy, hz):
    """Entry distance and |cos incidence| of a local-frame ray with a primitive (inf: miss)."""
    if kind == 0:  # box, slab method
        tmin = -math.inf
        tmax = math.inf
        axis_cos = 0.0
        for a in range(3):
            if a == 0:
                p, d, h = px, dx, hx
            elif a == 1:
                p, d, h = py, dy, hy
            else:
                p, d, h = pz, dz, hz
            if abs(d) < 1e-12:
                if abs(p) > h:
                    return math.inf, 0.0
                continue
            t1 = (-h - p) / d
            t2 = (h - p) / d
            if t1 > t2:
                t1, t2 = t2, t1
            if t1 > tmin:
                tmin = t1
                axis_cos = abs(d)
            if t2 < tmax:
                tmax = t2
            if tmin > tmax:
                return math.inf, 0.0
        if tmin <= 0.0:
            return math.inf, 0.0
        return tmin, axis_cos
    if kind == 1:  # vertical cylinder: radius hx, half height hz
        best = math.inf
        cos = 0.0
        a = dx * dx + dy * dy
        if a > 1e-12:
            b = px * dx + py * dy
            c = px * px + py * py - hx * hx
            disc = b * b - a * c
            if disc >= 0.0:
                t = (-b - math.sqrt(disc)) / a
                z = pz + t * dz
                if t > 0.0 and abs(z) <= hz:
                    best = t
                    cos = abs((px + t * dx) * dx + (py + t * dy) * dy) / hx
        cap = hz if pz > hz else (-hz if pz < -hz else 0.0)
        if cap != 0.0 and abs(dz) > 1e-12:
            t = (cap - pz) / dz
            if 0.0 < t < best:
                x = px + t * dx
                y = py + t * dy
                if x * x + y * y <= hx * hx:
                    best = t
                    cos = abs(dz)
        return best, cos
    # ellipsoid with semi-axes hx, hy, hz
    qx, qy, qz = px / hx, py / hy, pz / hz
    ex, ey, ez = dx / hx, dy / hy, dz / hz
    a = ex * ex + ey * ey + ez * ez
    b = qx * ex + qy * ey + qz * ez
    c = qx * qx + qy * qy + qz * qz - 1.0
    disc = b * b - a * c
    if disc < 0.0:
        return math.inf, 0.0
    t = (-b - math.sqrt(disc)) / a
    if t <= 0.0:
        return math.inf, 0.0
    nx = (qx + t * ex) / hx
    ny = (qy + t * ey) / hy
    nz = (qz + t * ez) / hz
    nn = math.sqrt(nx * nx + ny * ny + nz * nz)
    return t, abs(nx * dx + ny * dy + nz * dz) / nn


@nb.njit(cache=True)
def _exit(kind, px, py, pz, dx, dy, dz, hx, hy, hz):
    """Exit distance of a local-frame ray from a box or ellipsoid it enters (cylinders: side exit)."""
    if kind == 0:
        tmax = math.inf
        for p, d, h in ((px, dx, hx), (py, dy, hy), (pz, dz, hz)):
            if abs(d) > 1e-12:
                tmax = min(tmax, max((-h - p) / d, (h - p) / d))
        return tmax
    if kind == 1:
        hy = hx
        hz = math.inf
        dz = 0.0
    qx, qy, qz = px / hx, py / hy, pz / hz
    ex, ey, ez = dx / hx, dy / hy, dz / hz
    a = ex * ex + ey * ey + ez * ez
    b = qx * ex + qy * ey + qz * ez
    c = qx * qx + qy * qy + qz * qz - 1.0
    return (-b + math.sqrt(max(b * b - a * c, 0.0))) / a


@nb.njit(cache=True)
def _hash01(i, j, salt):
    """Deterministic pseudo-random number in (0, 1] from two integers and a salt."""
    x = math.sin(i * 12.9898 + j * 78.233 + salt) * 43758.5453
    return 1.0 - (x - math.floor(x))


@nb.njit(cache=True)
def bin_primitives(ox, oy, oz, kind, center, half, max_range, n_bins):
    """Cull and bin primitives around the origin.

    Returns:
        near ``(P,)`` nearest possible horizontal distance, el_lo/el_hi ``(P,)`` elevation interval
        (radians), start ``(n_bins + 1,) int64`` and items ``(M,) int64``: the primitives of bin b,
        nearest first, are ``items[start[b]:start[b + 1]]``.
    """
    n = kind.shape[0]
    near = np.empty(n)
    el_lo = np.empty(n)
    el_hi = np.empty(n)
    b_lo = np.zeros(n, np.int64)
    b_hi = np.zeros(n, np.int64)
    valid = np.zeros(n, np.bool_)
    bw = 2.0 * math.pi / n_bins
    for p in range(n):
        dx = center[p, 0] - ox
        dy = center[p, 1] - oy
        dist = math.sqrt(dx * dx + dy * dy)
        if kind[p] == 0:
            rb = math.sqrt(half[p, 0] ** 2 + half[p, 1] ** 2)
        else:
            rb = max(half[p, 0], half[p, 1])
        nr = dist - rb
        if nr > max_range:
            continue
        valid[p] = True
        nr = max(nr, 0.0)
        far = dist + rb
        near[p] = nr
        zmin = center[p, 2] - half[p, 2] - oz
        zmax = center[p, 2] + half[p, 2] - oz
        el_hi[p] = math.atan2(zmax, nr if zmax > 0 else far)
        el_lo[p] = math.atan2(zmin, far if zmin > 0 else nr)
        if dist <= rb + 1e-6:
            b_lo[p] = 0
            b_hi[p] = n_bins - 1
        else:
            ha = math.asin(rb / dist) + 1e-3
            ac = math.atan2(dy, dx)
            lo = math.floor((ac - ha + math.pi) / bw)
            hi = math.floor((ac + ha + math.pi) / bw)
            if hi - lo + 1 >= n_bins:
                lo, hi = 0, n_bins - 1
            b_lo[p] = lo
            b_hi[p] = hi
    order = np.argsort(near)
    count = np.zeros(n_bins + 1, np.int64)
    for p in order:
        if valid[p]:
            for b in range(b_lo[p], b_hi[p] + 1):
                count[(b % n_bins) + 1] += 1
    start = np.cumsum(count)
    fill = start[:-1].copy()
    items = np.empty(start[-1], np.int64)
    for p in order:
        if valid[p]:
            for b in range(b_lo[p], b_hi[p] + 1):
                bb = b % n_bins
                items[fill[bb]] = p
                fill[bb] += 1
    return near, el_lo, el_hi, start, items


@nb.njit(cache=True)
def ground_hits_frenet(origin, rot, dirs, ground):
    """The street's ground hit of every ray (road at z = 0, raised zones at the curb height).

    Returns:
        t ``(R,)`` distance (inf: no hit), raw class ``(R,) int32``, |cos incidence| ``(R,)``.
    """
    nr = dirs.shape[0]
    out_t = np.empty(nr)
    out_cls = np.empty(nr, np.int32)
    out_cos = np.empty(nr)
    ox, oy, oz = origin[0], origin[1], origin[2]
    for r in range(nr):
        sx, sy, sz = dirs[r, 0], dirs[r, 1], dirs[r, 2]
        dx = rot[0, 0] * sx + rot[0, 1] * sy + rot[0, 2] * sz
        dy = rot[1, 0] * sx + rot[1, 1] * sy + rot[1, 2] * sz
        dz = rot[2, 0] * sx + rot[2, 1] * sy + rot[2, 2] * sz
        t, cls, cos = _ground(ox, oy, oz, dx, dy, dz, ground)
        out_t[r] = t
        out_cls[r] = cls
        out_cos[r] = cos
    return out_t, out_cls, out_cos


@nb.njit(cache=True)
def cast_rays(origin, rot, dirs, prims, cull, n_bins, ground_hits, ground_refl, max_range, salt=0.0):
    """Cast sensor-frame rays ``dirs (R, 3)`` from ``origin (3,)`` rotated by ``rot (3, 3)``.

    ``ground_hits`` = (t, raw class, |cos|) of each ray's ground hit, from :func:`ground_hits_frenet`
    or :func:`dsnet_core.synth.ground.ground_hits_raster`.

    Vegetation is porous: a ray entering foliage returns from an exponentially distributed depth
    (mean ``FOLIAGE_DEPTH``, at most the far side), so crowns and hedges give volumetric, noisy
    points and let nearer-inside surfaces (trunks) show through. ``salt`` varies that draw per sweep.

    Returns:
        t ``(R,)`` hit distance (inf: none within ``max_range``), semantic ``(R,) int32`` raw id,
        instance ``(R,) int32``, cos ``(R,)`` |cos incidence|, reflectivity ``(R,)``.
    """
    kind, center, yaw, half, semantic, instance, reflectivity = prims
    near, el_lo, el_hi, start, items = cull
    g_t, g_cls, g_cos = ground_hits
    nr = dirs.shape[0]
    out_t = np.full(nr, math.inf)
    out_sem = np.zeros(nr, np.int32)
    out_inst = np.zeros(nr, np.int32)
    out_cos = np.zeros(nr)
    out_refl = np.zeros(nr)
    ox, oy, oz = origin[0], origin[1], origin[2]
    yc = np.cos(yaw)
    ys = np.sin(yaw)
    bw = 2.0 * math.pi / n_bins
    for r in range(nr):
        sx, sy, sz = dirs[r, 0], dirs[r, 1], dirs[r, 2]
        dx = rot[0, 0] * sx + rot[0, 1] * sy + rot[0, 2] * sz
        dy = rot[1, 0] * sx + rot[1, 1] * sy + rot[1, 2] * sz
        dz = rot[2, 0] * sx + rot[2, 1] * sy + rot[2, 2] * sz
        best, cls, cos = g_t[r], g_cls[r], g_cos[r]
        hit = -1
        el = math.asin(min(1.0, max(-1.0, dz)))
        b = min(int((math.atan2(dy, dx) + math.pi) / bw), n_bins - 1)
        for k in range(start[b], start[b + 1]):
            p = items[k]
            if near[p] >= best:
                break
            if el < el_lo[p] - 1e-4 or el > el_hi[p] + 1e-4:
                continue
            qx, qy, c, s = ox - center[p, 0], oy - center[p, 1], yc[p], ys[p]
            lx, ly, lz = c * qx + s * qy, -s * qx + c * qy, oz - center[p, 2]
            ex, ey = c * dx + s * dy, -s * dx + c * dy
            t, cs = _intersect(kind[p], lx, ly, lz, ex, ey, dz, half[p, 0], half[p, 1], half[p, 2])
            if t < best and semantic[p] == VEGETATION:
                t_out = _exit(kind[p], lx, ly, lz, ex, ey, dz, half[p, 0], half[p, 1], half[p, 2])
                t = min(t - FOLIAGE_DEPTH * math.log(_hash01(r, p, salt)), max(t, t_out))
            if t < best:
                best = t
                hit = p
                cos = cs
        if best > max_range:
            continue
        out_t[r] = best
        out_cos[r] = cos
        if hit >= 0:
            out_sem[r] = semantic[hit]
            out_inst[r] = instance[hit]
            out_refl[r] = reflectivity[hit]
        else:
            out_sem[r] = cls
            out_refl[r] = ground_refl[cls]
    return out_t, out_sem, out_inst, out_cos, out_refl
