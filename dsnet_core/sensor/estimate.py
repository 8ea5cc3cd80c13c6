"""Estimate a LiDAR from its log (``dsnet describe LOG --sensor``): the beam table, azimuth grid,
field of view, mounting, range limits, ray drop, range noise and remission, as a
:class:`~dsnet_core.sensor.card.SensorCard`.

How each value is measured, in the sensor's frame: a log in another frame (a vehicle frame, its
origin at the rear axle or on the ground) is first moved into it, from the sensor's centre and tilt
found in the first scan (:mod:`dsnet_core.sensor.origin`; the card's ``origin``):

- **beams**: the histogram of the points' elevation angles ``atan2(z, hypot(x, y))`` over many
  scans (points nearer than 2 m left out: parallax and rounding). Rays of one beam share one
  elevation, whatever they hit (the ground included) and however the sensor moves, so each beam is
  one peak: an exact one for a simulated sensor, a spread one for a real one (1 cm rounding, laser
  offsets); a peak is a beam when its prominence is at least half its height.
- **azimuth grid**: the median spacing of neighbouring points of a beam gives a first step; the
  number of firings per turn is then the integer ``W`` near it whose grid ``exp(i·W·azimuth)``
  the points follow best (coherence 1 = every point on the grid). A coherence below 0.5 is a
  sensor without a fixed azimuth grid: said in ``not_estimated``.
- **scan direction**: the sign of the azimuth step between consecutive points of a beam in the
  file's order.
- **field of view**: 360° less the widest azimuth gap without points in any scan.
- **mounting**: a RANSAC plane through the points below the sensor 3–25 m away, per scan; the
  height is its distance from the sensor origin, the tilt its normal (medians over scans).
- **ray drop**: each scan's points are put back into their range image (beam × azimuth column);
  a cell whose two azimuth neighbours returned at about the same range hit a surface, so an empty
  one is a dropped ray. Rates per beam and per range bin; the log's rate weights the range bins by
  the rays they hold.
- **range noise**: residuals of points on planar 2 m patches (PCA), divided by the cosine of
  the incidence angle (noise is along the ray), robust standard deviation (1.4826 · MAD).
- **remission**: quantiles, over the log and per range bin; the ground's median per incidence bin.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dsnet_core.errors import DataFormatError
from dsnet_core.sensor.beams import beam_peaks
from dsnet_core.sensor.card import RayDrop, Remission, SensorCard, SensorOrigin
from dsnet_core.sensor.origin import fit_origin, sharpness, to_sensor_frame

NEAR = 2.0  # metres: points nearer than this are left out of the elevation histogram
RANGE_EDGES = (0.0, 5.0, 10.0, 20.0, 30.0, 45.0, 60.0, 80.0, 100.0, 120.0, 150.0, 200.0, 300.0)
LEVELS = tuple(round(0.05 * k, 2) for k in range(21))
INCIDENCE_EDGES = (0.0, 0.2, 0.4, 0.6, 0.8, 1.0)
DEFAULT_HEIGHT = 1.73
ORIGIN_POINTS = 12_000  # points of the first scan the sensor's centre is searched with


class SensorEstimateError(DataFormatError):
    """A log holds nothing a sensor can be estimated from (no points, or no structure)."""


@dataclass
class SensorEstimate:
    """What :func:`estimate_sensor` found.

    Attributes:
        card: the sensor card (``card.not_estimated``: what could not be estimated, and why).
        frames_used: scans read.
        frames_total: scans in the log (the sequences asked for).
        diagnostics: numbers behind the estimate (azimuth coherence, ground inliers, …).
    """

    card: SensorCard
    frames_used: int
    frames_total: int
    diagnostics: dict[str, float] = field(default_factory=dict)


@dataclass
class _Scan:
    xyz: np.ndarray  # (N, 3) float64
    rem: np.ndarray  # (N,) float32
    rng: np.ndarray  # (N,) float64 range
    el: np.ndarray  # (N,) float64 elevation, degrees
    az: np.ndarray  # (N,) float64 azimuth, radians
    beam: np.ndarray | None = None  # (N,) int64


def estimate_sensor(
    reader,
    root: str | Path,
    sequences: list[str] | None = None,
    max_frames: int = 40,
    name: str = "sensor",
) -> SensorEstimate:
    """Estimate the sensor of ``reader``'s log from up to ``max_frames`` scans spread over it.

    Args:
        reader: a :class:`~dsnet_core.io.reader.LogReader`.
        root: the log's path (named in errors and recorded as the card's ``source``).
        sequences: the sequences to read (default all).
        max_frames: scans read at most (evenly spread over the log).
        name: the card's name.

    Raises:
        SensorEstimateError: no scan, no point, or every scan's points are one point.
    """
    refs = [(seq, ref) for seq in (sequences or reader.sequences()) for ref in reader.frames(seq)]
    if not refs:
        raise SensorEstimateError(root, "holds no scan to estimate a sensor from")
    pick = np.unique(np.linspace(0, len(refs) - 1, min(max_frames, len(refs))).round().astype(int))
    scans = [_read(reader.scan(refs[i][1])) for i in pick]
    scans = [s for s in scans if s.xyz.shape[0]]
    if not scans:
        raise SensorEstimateError(root, "its scans hold no point (every ray without a return)")
    lo = np.min([s.xyz.min(axis=0) for s in scans], axis=0)
    hi = np.max([s.xyz.max(axis=0) for s in scans], axis=0)
    if float(np.max(hi - lo)) < 1e-6:
        raise SensorEstimateError(
            root,
            f"every point of every scan is the same point {tuple(round(float(v), 3) for v in lo)}: "
            "no beam pattern, azimuth grid or range to estimate a sensor from",
        )
    missing: dict[str, str] = {}
    diag: dict[str, float] = {}
    single = len(scans) == 1
    scans, origin, sharp_scans = _sensor_frame(scans, diag)
    elevations = beam_peaks(np.concatenate([s.el[s.rng > NEAR] for s in sharp_scans]))
    if elevations.size == 0:
        raise SensorEstimateError(root, f"no point is farther than {NEAR} m: no beam pattern to estimate")
    if single:
        missing["elevations_deg"] = (
            "from 1 scan: not checked across scans, and beams without a return in it are missing"
        )
    edges = _midpoints(elevations)
    for s in scans:
        s.beam = np.searchsorted(edges, -s.el)  # beams top first: sort by -elevation
    steps, phases, coherence, spacing_cv = _azimuth_grid(scans[: max(3, min(len(scans), 3))], elevations.size)
    diag["azimuth_coherence"] = coherence
    if coherence < 0.5:
        missing["azimuth_steps"] = (
            f"the azimuth is not on a fixed grid (coherence {coherence:.2f}, spacing varies by "
            f"{100 * spacing_cv:.0f} %): {steps} is 360° / the median spacing of neighbouring points"
        )
    direction, share = _scan_direction(scans, steps)
    diag["scan_direction_share"] = share
    if direction is None:
        missing["scan_direction"] = (
            f"the points' order does not follow the spin ({100 * share:.0f} % of neighbouring steps increase)"
        )
    fov, center = _field_of_view(scans, steps)
    fits = [(s, _ground_plane(s, np.random.default_rng(k))) for k, s in enumerate(_spread(scans, 6))]
    ground = [(s, g) for s, g in fits if g is not None]
    if ground:
        height = float(np.median([g[0] for _, g in ground]))
        pitch = float(np.median([g[1] for _, g in ground]))
        roll = float(np.median([g[2] for _, g in ground]))
        diag["ground_scans"] = float(len(ground))
    else:
        height, pitch, roll = DEFAULT_HEIGHT, 0.0, 0.0
        missing["mount_height_m"] = (
            f"no ground plane below the sensor 3–25 m away: {DEFAULT_HEIGHT} m assumed"
        )
    ranges = np.concatenate([s.rng for s in scans])
    min_range, max_range = float(ranges.min()), float(ranges.max())
    range_edges = _range_edges(max_range)
    drop, drop_diag = _ray_drop(_spread(scans, 12), elevations.size, steps, phases, range_edges)
    diag.update(drop_diag)
    if drop is None:
        missing["ray_drop"] = "no surface seen by neighbouring rays: no drop rate measured (0 assumed)"
        nb = len(range_edges) - 1
        drop = RayDrop(rate=0.0, per_beam=(0.0,) * elevations.size, beam_factor=(1.0,) * elevations.size,
                       range_edges_m=range_edges, by_range=(0.0,) * nb)  # fmt: skip
    elif coherence < 0.5:
        missing["ray_drop"] = "measured on an approximate azimuth grid (see azimuth_steps): a rough figure"
    noise, patches = _range_noise(scans[:3])
    diag["planar_patches"] = float(patches)
    if noise is None:
        noise = 0.02
        missing["range_noise_m"] = "too few planar surfaces (under 20 patches of 2 m): 0.02 m assumed"
    remission = _remission(scans, range_edges, ground)
    if float(np.max([s.rem.max() for s in scans])) <= 0.0:
        missing["remission"] = "every remission is 0 (the log has no intensity)"
    period = _frame_period(reader, refs)
    if period is None:
        missing["frame_period_s"] = (
            "1 scan: no time between scans" if len(refs) == 1 else "the log has no timestamps"
        )
    card = SensorCard(
        name=name,
        source=str(root),
        beams=int(elevations.size),
        elevations_deg=tuple(round(float(e), 4) for e in elevations),
        azimuth_steps=int(steps),
        fov_deg=round(fov, 3),
        fov_center_deg=round(center, 3),
        scan_direction=direction,
        frame_period_s=period,
        origin=origin,
        mount_height_m=round(height, 4),
        mount_pitch_deg=round(pitch, 3),
        mount_roll_deg=round(roll, 3),
        min_range_m=round(min_range, 3),
        max_range_m=round(max(max_range, min_range + 1e-3), 3),
        returns_per_scan=round(float(np.mean([s.xyz.shape[0] for s in scans])), 1),
        range_noise_m=round(float(noise), 5),
        ray_drop=drop,
        remission=remission,
        not_estimated=missing,
    )
    return SensorEstimate(card, len(scans), len(refs), diag)


def _sensor_frame(
    scans: list[_Scan], diag: dict[str, float]
) -> tuple[list[_Scan], SensorOrigin, list[_Scan]]:
    """The scans moved into the sensor's frame (:mod:`dsnet_core.sensor.origin`, fitted on the first
    scan), the origin found, and the scans the beam table is measured from: those at least 60 % as
    sharp as the sharpest (a sensor without motion compensation smears its beams while the vehicle
    moves fast: PandaSet's sequence 30 starts standing and ends at 5 m/s)."""
    fit = fit_origin(scans[0].xyz, max_points=ORIGIN_POINTS)
    diag["origin_sharpness"] = fit.sharpness
    diag["origin_sharpness_at_log_origin"] = fit.sharpness_at_log_origin
    if not fit.moved:
        return scans, fit.origin, scans
    moved = [_from_xyz(to_sensor_frame(s.xyz, fit.origin), s.rem) for s in scans]
    sharp = np.array([sharpness(s.xyz[:: max(1, s.xyz.shape[0] // 8000)]) for s in moved])
    keep = [s for s, v in zip(moved, sharp, strict=True) if v >= 0.6 * sharp.max()]
    diag["origin_sharp_scans"] = float(len(keep))
    return moved, fit.origin, keep


def _spread(scans: list[_Scan], n: int) -> list[_Scan]:
    """At most ``n`` of ``scans``, evenly spread."""
    if len(scans) <= n:
        return scans
    return [scans[i] for i in np.linspace(0, len(scans) - 1, n).round().astype(int)]


def _read(scan: np.ndarray) -> _Scan:
    xyz = np.asarray(scan[:, :3], dtype=np.float64)
    rng = np.linalg.norm(xyz, axis=1)
    keep = rng > 1e-3  # (0, 0, 0): a no-return some formats write
    xyz = xyz[keep]
    rem = np.asarray(scan[keep, 3], dtype=np.float32) if scan.shape[1] > 3 else np.zeros(len(xyz), np.float32)
    return _from_xyz(xyz, rem)


def _from_xyz(xyz: np.ndarray, rem: np.ndarray) -> _Scan:
    rng = np.linalg.norm(xyz, axis=1)
    horiz = np.hypot(xyz[:, 0], xyz[:, 1])
    el = np.degrees(np.arctan2(xyz[:, 2], horiz))
    az = np.arctan2(xyz[:, 1], xyz[:, 0])
    return _Scan(xyz, rem, rng, el, az)


def _midpoints(elevations: np.ndarray) -> np.ndarray:
    """Boundaries between beams in ``-elevation`` order (for ``searchsorted(-el)``)."""
    neg = -elevations  # increasing
    return (neg[1:] + neg[:-1]) / 2


def _azimuth_grid(scans: list[_Scan], beams: int) -> tuple[int, np.ndarray, float, float]:
    """(firings per turn, ``(B,)`` phase of each beam's grid in columns, coherence, spacing CV)."""
    diffs = []
    for s in scans:
        order = np.lexsort((s.az, s.beam))
        az, beam = s.az[order], s.beam[order]
        d = np.diff(az)
        d = d[(np.diff(beam) == 0) & (d > 1e-9)]
        diffs.append(d)
    d = np.concatenate(diffs)
    if d.size == 0:
        return 1, np.zeros(beams), 0.0, 0.0
    step = float(np.median(d))
    near = d[d < 1.5 * step]
    spacing_cv = float(np.std(near) / np.mean(near)) if near.size else 0.0
    w0 = 2 * math.pi / step
    az = np.concatenate([s.az for s in scans])
    beam = np.concatenate([s.beam for s in scans])
    if az.size > 60_000:
        sel = np.random.default_rng(0).choice(az.size, 60_000, replace=False)
        az, beam = az[sel], beam[sel]
    counts = np.bincount(beam, minlength=beams).astype(np.float64)
    best_w, best_c, best_phase = max(1, round(w0)), -1.0, np.zeros(beams)
    span = min(int(w0 * 0.03) + 1, 150)  # at most 301 candidates
    for w in range(max(1, round(w0) - span), round(w0) + span + 1):
        z = np.exp(2j * math.pi * ((az + math.pi) * w / (2 * math.pi) - 0.5))  # 1 on the grid (j + ½)·step
        # per beam (lasers may fire at their own azimuth offset), weighted by points
        re = np.bincount(beam, weights=z.real, minlength=beams)
        im = np.bincount(beam, weights=z.imag, minlength=beams)
        mag = np.hypot(re, im)
        c = float(mag.sum() / max(counts.sum(), 1.0))
        if c > best_c:
            best_w, best_c = w, c
            best_phase = np.arctan2(im, re) / (2 * math.pi)
    if best_c < 0.5:
        best_w = min(max(1, round(w0)), 100_000)
    return int(best_w), best_phase, best_c, spacing_cv


def _scan_direction(scans: list[_Scan], steps: int) -> tuple[str | None, float]:
    step = 2 * math.pi / steps
    pos = tot = 0
    for s in scans[:5]:
        d = np.diff(s.az)
        d = (d + math.pi) % (2 * math.pi) - math.pi
        ok = (np.diff(s.beam) == 0) & (np.abs(d) > 0.3 * step) & (np.abs(d) < 3.5 * step)
        pos += int((d[ok] > 0).sum())
        tot += int(ok.sum())
    share = pos / tot if tot else 0.5
    if tot >= 100 and share >= 0.8:
        return "counter-clockwise", share
    if tot >= 100 and share <= 0.2:
        return "clockwise", share
    return None, share


def _field_of_view(scans: list[_Scan], steps: int) -> tuple[float, float]:
    """(width, centre) in degrees: 360° less the widest azimuth gap without points."""
    az = np.concatenate([s.az[::3] for s in scans])
    bins = np.bincount(((np.degrees(az) + 180.0) % 360.0).astype(np.int64), minlength=360)[:360]
    empty = bins == 0
    if not empty.any():
        return 360.0, 0.0
    # widest circular run of empty 1° bins
    run = best = best_end = 0
    for k in range(720):
        run = run + 1 if empty[k % 360] else 0
        if run > best:
            best, best_end = min(run, 360), k
    if best < 3:
        return 360.0, 0.0
    gap_centre = math.radians((best_end - best / 2 + 0.5) % 360.0 - 180.0)
    rel = (az - gap_centre) % (2 * math.pi)  # in (0, 2π): the occupied arc, away from the gap
    lo, hi = float(rel.min()), float(rel.max())
    width = math.degrees(hi - lo) + 360.0 / steps
    centre = math.degrees((gap_centre + (lo + hi) / 2 + math.pi) % (2 * math.pi) - math.pi)
    return min(width, 360.0), centre


def _ground_plane(s: _Scan, rng: np.random.Generator) -> tuple[float, float, float, np.ndarray] | None:
    """(height m, pitch °, roll °, inlier mask) of the ground plane of one scan, or None."""
    horiz = np.hypot(s.xyz[:, 0], s.xyz[:, 1])
    cand = np.flatnonzero((horiz > 3.0) & (horiz < 25.0) & (s.xyz[:, 2] < 0.0))
    if cand.size < 200:
        return None
    pts = s.xyz[cand]
    if pts.shape[0] > 20_000:
        pts = pts[rng.choice(pts.shape[0], 20_000, replace=False)]
    tri = pts[rng.integers(0, pts.shape[0], (400, 3))]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(n, axis=1)
    ok = norm > 1e-9
    n, tri = n[ok] / norm[ok, None], tri[ok]
    n *= np.sign(n[:, 2:3]) + (n[:, 2:3] == 0)
    ok = n[:, 2] > 0.8  # within ~37° of the sensor's up
    if not ok.any():
        return None
    n, p0 = n[ok], tri[ok, 0]
    d = -(n * p0).sum(axis=1)
    # a tight band, so that a plane mixing the road with a raised kerb or sidewalk scores low
    inliers = (np.abs(pts @ n.T + d) < 0.02).sum(axis=0)
    k = int(np.argmax(inliers))
    if inliers[k] < 100:
        return None
    normal, offset = n[k], d[k]
    for thr in (0.03, 0.02, 0.02):  # least-squares refinement on the inliers
        res = s.xyz @ normal + offset
        inl = (np.abs(res) < thr) & (horiz > 3.0) & (horiz < 25.0)
        if inl.sum() < 100:
            return None
        q = s.xyz[inl]
        c = q.mean(axis=0)
        normal = np.linalg.svd(q - c, full_matrices=False)[2][-1]
        normal = normal if normal[2] > 0 else -normal
        offset = -float(normal @ c)
    mask = np.abs(s.xyz @ normal + offset) < 0.02
    pitch = -math.degrees(math.asin(max(-1.0, min(1.0, float(normal[0])))))
    roll = math.degrees(math.atan2(float(normal[1]), float(normal[2])))
    return abs(offset), pitch, roll, mask


def _range_edges(max_range: float) -> tuple[float, ...]:
    edges = [e for e in RANGE_EDGES if e < max_range]
    top = float(math.ceil(max_range))
    return (*edges, top if top > edges[-1] else edges[-1] + 1.0)


def _ray_drop(scans: list[_Scan], beams: int, steps: int, phases: np.ndarray, edges: tuple[float, ...]):
    """A :class:`RayDrop` from the scans' range images (None: no surface seen by neighbours)."""
    nb = len(edges) - 1
    e = np.asarray(edges)
    empty_b = np.zeros(beams)
    cand_b = np.zeros(beams)
    empty_r = np.zeros(nb)
    cand_r = np.zeros(nb)
    returns_r = np.zeros(nb)
    collisions = cells = 0
    cand_ranges, cand_beams, cand_empty = [], [], []
    for s in scans:
        u = (s.az + math.pi) * steps / (2 * math.pi) - 0.5
        col = np.rint(u - phases[s.beam]).astype(np.int64) % steps
        image = np.full((beams, steps), np.nan)
        flat = s.beam * steps + col
        image.flat[flat] = s.rng
        cells += flat.size
        collisions += flat.size - np.unique(flat).size
        left, right = np.roll(image, 1, axis=1), np.roll(image, -1, axis=1)
        both = np.isfinite(left) & np.isfinite(right)
        mean = np.where(both, (left + right) / 2, 0.0)
        cand = both & (np.abs(left - right) <= 0.03 * mean + 0.1)
        empty = cand & np.isnan(image)
        bb, _ = np.nonzero(cand)
        cand_ranges.append(mean[cand])
        cand_beams.append(bb)
        cand_empty.append(empty[cand])
        returns_r += np.bincount(
            np.clip(np.searchsorted(e, s.rng, side="right") - 1, 0, nb - 1), minlength=nb
        )
    r = np.concatenate(cand_ranges)
    if r.size < 100:
        return None, {}
    b = np.concatenate(cand_beams)
    emp = np.concatenate(cand_empty).astype(np.float64)
    rb = np.clip(np.searchsorted(e, r, side="right") - 1, 0, nb - 1)
    cand_r += np.bincount(rb, minlength=nb)
    empty_r += np.bincount(rb, weights=emp, minlength=nb)
    cand_b += np.bincount(b, minlength=beams)
    empty_b += np.bincount(b, weights=emp, minlength=beams)
    known = cand_r >= 30
    rate_r = np.where(known, empty_r / np.maximum(cand_r, 1), np.nan)
    if not known.any():
        rate_r[:] = float(emp.mean())
    else:  # bins without enough cells take their nearest measured neighbour's rate
        idx = np.flatnonzero(known)
        rate_r = rate_r[idx[np.argmin(np.abs(np.arange(nb)[:, None] - idx[None]), axis=1)]]
    rays_r = returns_r / np.maximum(1.0 - rate_r, 1e-3)
    rate = float((rays_r * rate_r).sum() / max(rays_r.sum(), 1.0))
    per_beam = np.where(cand_b >= 30, empty_b / np.maximum(cand_b, 1), rate)
    expected_b = np.bincount(b, weights=rate_r[rb], minlength=beams)
    factor = np.where((cand_b >= 30) & (expected_b > 0), empty_b / np.maximum(expected_b, 1e-9), 1.0)
    drop = RayDrop(
        rate=round(rate, 5),
        per_beam=tuple(round(float(v), 5) for v in per_beam),
        beam_factor=tuple(round(float(v), 4) for v in np.clip(factor, 0.0, 20.0)),
        range_edges_m=edges,
        by_range=tuple(round(float(v), 5) for v in rate_r),
    )
    return drop, {"grid_collisions": collisions / max(cells, 1), "drop_cells": float(r.size)}


def _range_noise(scans: list[_Scan], voxel: float = 2.0) -> tuple[float | None, int]:
    """(robust std of the range error on planar patches, number of patches)."""
    errs = []
    patches = 0
    for s in scans:
        key = np.floor(s.xyz / voxel).astype(np.int64)
        _, inv, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
        inv = inv.ravel()
        ok = counts[inv] >= 15
        p, inv_ok = s.xyz[ok], inv[ok]
        if p.shape[0] == 0:
            continue
        _, v = np.unique(inv_ok, return_inverse=True)
        v = v.ravel()
        nv = int(v.max()) + 1
        cnt = np.bincount(v, minlength=nv).astype(np.float64)
        mean = np.stack([np.bincount(v, weights=p[:, k], minlength=nv) for k in range(3)], 1) / cnt[:, None]
        q = p - mean[v]
        cov = np.empty((nv, 3, 3))
        for i in range(3):
            for j in range(i, 3):
                cov[:, i, j] = cov[:, j, i] = np.bincount(v, weights=q[:, i] * q[:, j], minlength=nv) / cnt
        lam, vec = np.linalg.eigh(cov)
        planar = (lam[:, 1] > 0.05) & (lam[:, 0] < 0.03 * lam[:, 1])
        patches += int(planar.sum())
        normal = vec[:, :, 0]
        sel = planar[v]
        res = (q[sel] * normal[v[sel]]).sum(axis=1)
        ray = p[sel] / np.linalg.norm(p[sel], axis=1, keepdims=True)
        cos = np.abs((ray * normal[v[sel]]).sum(axis=1))
        dof = np.sqrt(cnt[v[sel]] / (cnt[v[sel]] - 3))
        good = cos > 0.3
        errs.append(res[good] / cos[good] * dof[good])
    if patches < 20 or not errs:
        return None, patches
    e = np.concatenate(errs)
    if e.size < 200:
        return None, patches
    return float(1.4826 * np.median(np.abs(e - np.median(e)))), patches


def _remission(scans: list[_Scan], edges: tuple[float, ...], ground: list) -> Remission:
    rem = np.concatenate([s.rem for s in scans]).astype(np.float64)
    rng = np.concatenate([s.rng for s in scans])
    levels = np.asarray(LEVELS)
    overall = np.quantile(rem, levels)
    e = np.asarray(edges)
    rb = np.clip(np.searchsorted(e, rng, side="right") - 1, 0, len(edges) - 2)
    by_range = []
    for k in range(len(edges) - 1):
        sel = rem[rb == k]
        by_range.append(np.quantile(sel, levels) if sel.size >= 100 else overall)
    inc_edges = np.asarray(INCIDENCE_EDGES)
    medians: list[float | None] = [None] * (len(INCIDENCE_EDGES) - 1)
    if ground:
        cos_all, rem_all = [], []
        for s, g in ground:
            mask = g[3]
            p, r = math.radians(g[1]), math.radians(g[2])
            normal = np.array([-math.sin(p), math.sin(r) * math.cos(p), math.cos(r) * math.cos(p)])
            cos_all.append(np.abs(s.xyz[mask] @ normal) / s.rng[mask])
            rem_all.append(s.rem[mask])
        cos, grem = np.concatenate(cos_all), np.concatenate(rem_all)
        ib = np.clip(np.searchsorted(inc_edges, cos, side="right") - 1, 0, len(inc_edges) - 2)
        medians = [
            float(round(np.median(grem[ib == k]), 4)) if (ib == k).sum() >= 50 else None
            for k in range(len(medians))
        ]

    def clean(q: np.ndarray) -> tuple[float, ...]:
        q = np.clip(np.maximum.accumulate(np.round(q, 4)), 0.0, 1.0)
        return tuple(float(v) for v in q)

    return Remission(
        levels=LEVELS,
        quantiles=clean(overall),
        range_edges_m=edges,
        by_range=tuple(clean(q) for q in by_range),
        incidence_edges=INCIDENCE_EDGES,
        median_by_incidence=tuple(medians),
    )


def _frame_period(reader, refs) -> float | None:
    gaps = []
    for (seq_a, a), (seq_b, b) in itertools.pairwise(refs):
        if seq_a != seq_b:
            continue
        ta, tb = reader.timestamp(a), reader.timestamp(b)
        if ta is not None and tb is not None and tb > ta:
            gaps.append(tb - ta)
    return round(float(np.median(gaps)), 5) if gaps else None
