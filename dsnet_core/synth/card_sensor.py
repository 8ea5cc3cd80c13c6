"""Rendering with a sensor card (``dsnet synth --sensor-card CARD`` / ``--like LOG``).

A card becomes a :class:`CardSpec`: the card's beam table, azimuth grid (only the columns within its
field of view, in its scan direction), mounting height and tilt, range limits and range noise; its
ray drop replaces the presets' model (a ray of beam b hitting at range r is lost with probability
``beam_factor[b] · by_range(r)``, ``by_range`` interpolated between bin centres), and its remission
is the generator's own (material, incidence, range fall-off) mapped, per range bin, onto the
card's quantiles by rank, so the rendered remission follows the card's distribution while bright
materials stay brighter than dark ones.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba as nb
import numpy as np

from dsnet_core.sensor.card import SensorCard
from dsnet_core.synth.sensor import LidarSpec
from dsnet_core.synth.variation import SequenceSetup


@dataclass(frozen=True)
class CardSpec(LidarSpec):
    """A LiDAR from a sensor card (see the module docstring).

    Attributes (beyond :class:`LidarSpec`'s; ``dropout`` and ``far_dropout`` are unused):
        fov_deg, fov_center_deg: horizontal field of view and its centre (degrees).
        clockwise: each beam's points in decreasing azimuth.
        beam_factor: ``(B,)`` per-beam multiplier of the range drop rate.
        drop_edges: ``(K + 1,)`` range bin edges (metres); drop_by_range: ``(K,)`` rates.
        remission_levels: ``(Q,)`` quantile levels; remission_edges: ``(M + 1,)`` range bin edges;
        remission_by_range: ``(M, Q)`` remission quantiles per range bin.
    """

    fov_deg: float = 360.0
    fov_center_deg: float = 0.0
    clockwise: bool = False
    beam_factor: tuple[float, ...] = ()
    drop_edges: tuple[float, ...] = ()
    drop_by_range: tuple[float, ...] = ()
    remission_levels: tuple[float, ...] = ()
    remission_edges: tuple[float, ...] = ()
    remission_by_range: tuple[tuple[float, ...], ...] = ()

    def columns(self) -> np.ndarray:
        """``(C,) int64`` the azimuth columns (of ``azimuth_steps`` per turn) within the field of view,
        in scan order."""
        j = np.arange(self.azimuth_steps)
        if self.fov_deg < 360.0:
            az = np.degrees((j + 0.5) * (2 * np.pi / self.azimuth_steps) - np.pi)
            off = (az - self.fov_center_deg + 180.0) % 360.0 - 180.0
            j = j[np.abs(off) <= self.fov_deg / 2]
        return j[::-1].copy() if self.clockwise else j

    @property
    def rays(self) -> int:
        return self.beams * self.columns().size

    def directions(self) -> np.ndarray:
        """Unit ray directions ``(B * C, 3) float64``, beam-major, the columns of :meth:`columns`."""
        el = np.deg2rad(np.asarray(self.elevations_deg, dtype=np.float64))[:, None]
        az = (self.columns().astype(np.float64) + 0.5) * (2 * np.pi / self.azimuth_steps) - np.pi
        el, az = np.broadcast_arrays(el, az[None, :])
        d = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=-1)
        return d.reshape(-1, 3)

    def simulate(self, dirs, hit_range, cos_incidence, reflectivity, semantic, instance, rng):
        """Geometric hits → a scan with the card's drop, noise and remission (arguments and returns
        as :func:`~dsnet_core.synth.sensor.simulate_returns`)."""
        edges = np.asarray(self.drop_edges, dtype=np.float64)
        centres = (edges[1:] + edges[:-1]) / 2
        params = np.array([self.range_noise, self.min_range, self.max_range, self.falloff], dtype=np.float64)
        scan, label = _card_returns(
            dirs,
            hit_range,
            cos_incidence,
            reflectivity,
            semantic,
            instance,
            params,
            np.asarray(self.beam_factor, dtype=np.float64),
            centres,
            np.asarray(self.drop_by_range, dtype=np.float64),
            rng,
        )
        scan[:, 3] = self._remission(scan)
        return scan, label

    def _remission(self, scan: np.ndarray) -> np.ndarray:
        """``(N,) float32``: the simulated remission mapped by rank onto the card's quantiles."""
        out = scan[:, 3].copy()
        r = np.linalg.norm(scan[:, :3].astype(np.float64), axis=1)
        edges = np.asarray(self.remission_edges, dtype=np.float64)
        levels = np.asarray(self.remission_levels, dtype=np.float64)
        bins = np.clip(np.searchsorted(edges, r, side="right") - 1, 0, len(edges) - 2)
        for k in range(len(edges) - 1):
            idx = np.flatnonzero(bins == k)
            if idx.size == 0:
                continue
            rank = np.empty(idx.size)
            rank[np.argsort(out[idx], kind="stable")] = (np.arange(idx.size) + 0.5) / idx.size
            quant = np.asarray(self.remission_by_range[k], dtype=np.float64)
            out[idx] = np.interp(rank, levels, quant).astype(np.float32)
        return out


@nb.njit(cache=True)
def _card_returns(
    dirs, hit_range, cos_incidence, reflectivity, semantic, instance, params, factor, centres, rates, rng
):
    noise, min_range, max_range, falloff = params[0], params[1], params[2], params[3]
    n = hit_range.shape[0]
    per_beam = n // factor.shape[0]
    scan = np.empty((n, 4), np.float32)
    label = np.empty(n, np.uint32)
    k = 0
    for i in range(n):
        r = hit_range[i]
        if not (min_range <= r <= max_range):
            continue
        p = factor[i // per_beam] * np.interp(r, centres, rates)
        if rng.random() < min(p, 0.99):
            continue
        m = r + rng.normal(0.0, noise)
        scan[k, 0] = dirs[i, 0] * m
        scan[k, 1] = dirs[i, 1] * m
        scan[k, 2] = dirs[i, 2] * m
        signal = min(max(reflectivity[i] * (0.35 + 0.65 * cos_incidence[i]), 0.0), 1.0)
        scan[k, 3] = signal * math.exp(-r / falloff) + rng.normal(0.0, 0.02)
        label[k] = np.uint32(semantic[i]) | (np.uint32(instance[i]) << np.uint32(16))
        k += 1
    return scan[:k].copy(), label[:k].copy()


def spec_from_card(card: SensorCard) -> CardSpec:
    """The :class:`CardSpec` that renders ``card``."""
    drop, rem = card.ray_drop, card.remission
    return CardSpec(
        name=card.name,
        elevations_deg=tuple(card.elevations_deg),
        azimuth_steps=card.azimuth_steps,
        height=card.mount_height_m,
        range_noise=card.range_noise_m,
        dropout=0.0,
        far_dropout=0.0,
        min_range=card.min_range_m,
        max_range=card.max_range_m,
        fov_deg=card.fov_deg,
        fov_center_deg=card.fov_center_deg,
        clockwise=card.scan_direction == "clockwise",
        beam_factor=tuple(drop.beam_factor),
        drop_edges=tuple(drop.range_edges_m),
        drop_by_range=tuple(drop.by_range),
        remission_levels=tuple(rem.levels),
        remission_edges=tuple(rem.range_edges_m),
        remission_by_range=tuple(tuple(q) for q in rem.by_range),
    )


def setup_from_card(card: SensorCard, style: str = "classic") -> SequenceSetup:
    """A sequence setup that renders ``style``'s street with ``card``'s sensor and tilt (nothing drawn
    about the sensor: the card fixes it; the street's materials keep their defaults)."""
    return SequenceSetup(
        style,
        f"card:{card.name}",
        True,
        spec_from_card(card),
        card.mount_pitch_deg,
        card.mount_roll_deg,
        None,
    )
