"""Spinning multi-beam LiDAR models: beam layout, and how a geometric hit becomes a return
(range noise, dropout, remission from material and incidence angle)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba as nb
import numpy as np

from dsnet_core.errors import ConfigError


@dataclass(frozen=True)
class LidarSpec:
    """A spinning LiDAR.

    Attributes:
        name: preset name.
        elevations_deg: ``(B,)`` beam elevations, degrees, top beam first.
        azimuth_steps: firings per revolution and beam.
        height: mounting height above the road (metres).
        range_noise: standard deviation of the range error (metres).
        dropout: probability that any return is lost.
        far_dropout: extra loss probability at ``max_range`` for a black target (grows with range²).
        min_range: returns closer than this are discarded (metres).
        max_range: returns farther than this are discarded (metres).
        beam_gains: ``(B,)`` per-laser remission gain (real units show ring-to-ring intensity
            differences); empty means 1 for every beam.
        remission_gain: global remission gain (multiplies every beam's gain).
        falloff: range fall-off of remission, ``exp(-r / falloff)`` (metres).
    """

    name: str
    elevations_deg: tuple[float, ...]
    azimuth_steps: int
    height: float = 1.73
    range_noise: float = 0.02
    dropout: float = 0.04
    far_dropout: float = 0.6
    min_range: float = 1.0
    max_range: float = 120.0
    beam_gains: tuple[float, ...] = ()
    remission_gain: float = 1.0
    falloff: float = 250.0

    @property
    def beams(self) -> int:
        return len(self.elevations_deg)

    @property
    def rays(self) -> int:
        return self.beams * self.azimuth_steps

    def simulate(
        self,
        dirs: np.ndarray,
        hit_range: np.ndarray,
        cos_incidence: np.ndarray,
        reflectivity: np.ndarray,
        semantic: np.ndarray,
        instance: np.ndarray,
        rng: np.random.Generator,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Geometric hits → a scan (see :func:`simulate_returns`; a sensor card's spec overrides it)."""
        params = np.array(
            [self.range_noise, self.dropout, self.far_dropout, self.min_range, self.max_range, self.falloff],
            dtype=np.float64,
        )
        gains = np.asarray(self.beam_gains or (1.0,) * self.beams, dtype=np.float64) * self.remission_gain
        return _returns(dirs, hit_range, cos_incidence, reflectivity, semantic, instance, params, gains, rng)

    def directions(self) -> np.ndarray:
        """Unit ray directions in the sensor frame, ``(B * W, 3) float64``, beam-major order.

        Azimuth 0 looks along +x (forward), increasing counter-clockwise (towards +y, left).
        """
        el = np.deg2rad(np.asarray(self.elevations_deg, dtype=np.float64))[:, None]
        az = (np.arange(self.azimuth_steps, dtype=np.float64) + 0.5) * (2 * np.pi / self.azimuth_steps)
        az = az[None, :] - np.pi
        el, az = np.broadcast_arrays(el, az)
        d = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=-1)
        return d.reshape(-1, 3)


def _hdl64_elevations() -> tuple[float, ...]:
    # Two blocks like the HDL-64E: 32 upper lasers at ~1/3°, 32 lower lasers at ~1/2° spacing.
    upper = np.linspace(2.0, -8.33, 32)
    lower = np.linspace(-8.83, -24.9, 32)
    return tuple(float(v) for v in np.concatenate([upper, lower]))


def _vlp32_elevations() -> tuple[float, ...]:
    # VLP-32C-like: dense around the horizon, sparse towards +15° and −25°.
    u = np.linspace(-1.0, 1.0, 32)
    el = np.where(u >= 0, 15.0, -25.0) * np.abs(u) ** 2.2
    return tuple(float(v) for v in np.sort(el)[::-1])


def _gains(beams: int, spread: float, seed: int | None = None) -> tuple[float, ...]:
    # fixed per model (seeded by the beam count), like the factory calibration of one unit
    rng = np.random.default_rng(beams if seed is None else seed)
    return tuple(float(g) for g in rng.uniform(1 - spread, 1 + spread, beams))


def _uniform_elevations(beams: int, top: float, bottom: float) -> tuple[float, ...]:
    return tuple(float(v) for v in np.linspace(top, bottom, beams))


SENSORS: dict[str, LidarSpec] = {
    "hdl64": LidarSpec("hdl64", _hdl64_elevations(), 2048, max_range=120.0, beam_gains=_gains(64, 0.25)),
    "vlp32": LidarSpec("vlp32", _vlp32_elevations(), 1024, max_range=100.0, beam_gains=_gains(32, 0.1)),
    # nuScenes' HDL-32E: 32 beams evenly from +10° to −30°, 1084 firings per turn at 20 Hz
    "nuscenes32": LidarSpec(
        "nuscenes32",
        _uniform_elevations(32, 10.0, -30.0),
        1084,
        height=1.84,
        max_range=70.0,
        beam_gains=_gains(32, 0.15, seed=3201),
    ),
    # Ouster OS1-like: beams evenly over ±22.5°
    "ouster64": LidarSpec(
        "ouster64",
        _uniform_elevations(64, 22.5, -22.5),
        2048,
        max_range=120.0,
        beam_gains=_gains(64, 0.08, seed=6401),
    ),
    "ouster128": LidarSpec(
        "ouster128",
        _uniform_elevations(128, 22.5, -22.5),
        1024,
        max_range=120.0,
        beam_gains=_gains(128, 0.08, seed=12801),
    ),
    # VLP-16: 16 beams 2° apart over ±15°, 0.2° azimuth steps at 10 Hz
    "vlp16": LidarSpec(
        "vlp16",
        _uniform_elevations(16, 15.0, -15.0),
        1800,
        max_range=100.0,
        beam_gains=_gains(16, 0.1, seed=1601),
    ),
}
LEGACY_SENSORS = ("hdl64", "vlp32")  # their default output is pinned byte for byte


def get_sensor(name: str) -> LidarSpec:
    """The preset called ``name`` (a key of :data:`SENSORS`).

    Raises:
        ConfigError: unknown name.
    """
    try:
        return SENSORS[name]
    except KeyError:
        raise ConfigError(f"unknown LiDAR model {name!r}; known: {sorted(SENSORS)}") from None


def simulate_returns(
    spec: LidarSpec,
    dirs: np.ndarray,
    hit_range: np.ndarray,
    cos_incidence: np.ndarray,
    reflectivity: np.ndarray,
    semantic: np.ndarray,
    instance: np.ndarray,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray]:
    """Turn geometric hits into a scan: range noise, dropout, remission, labels.

    A return is lost with probability ``dropout + far_dropout · (r / max_range)² · (1 − signal)``,
    where ``signal = reflectivity · (0.35 + 0.65 · cos incidence)`` (dark, grazing, far surfaces drop
    more); remission is ``gain(beam) · remission_gain · signal · exp(−r / falloff)`` plus noise, clipped
    to [0, 1]. A sensor card's spec (:class:`~dsnet_core.synth.card_sensor.CardSpec`) has its own
    ray drop and remission (its :meth:`LidarSpec.simulate`).

    Args:
        dirs: ``(R, 3) float64`` unit ray directions in the sensor frame, beam-major
            (:meth:`LidarSpec.directions` order; the beam of ray i is ``i // azimuth_steps``).
        hit_range: ``(R,) float64`` distance to the first surface along each ray (inf: no hit), metres.
        cos_incidence: ``(R,) float64`` |cos| of the angle between ray and surface normal.
        reflectivity: ``(R,) float64`` material reflectivity in [0, 1].
        semantic, instance: ``(R,) int32`` raw class and instance id of the surface hit.
        rng: draws the noise (advanced; deterministic output for a seeded generator).

    Returns:
        scan ``(N, 4) float32`` (x, y, z metres in the sensor frame; remission) and label ``(N,) uint32``
        (raw semantic | instance << 16), rays in ``dirs`` order.
    """
    return spec.simulate(dirs, hit_range, cos_incidence, reflectivity, semantic, instance, rng)


@nb.njit(cache=True)
def _returns(dirs, hit_range, cos_incidence, reflectivity, semantic, instance, params, gains, rng):
    noise, dropout, far_dropout, min_range, max_range = params[0], params[1], params[2], params[3], params[4]
    falloff = params[5]
    n = hit_range.shape[0]
    per_beam = n // gains.shape[0]
    scan = np.empty((n, 4), np.float32)
    label = np.empty(n, np.uint32)
    k = 0
    for i in range(n):
        r = hit_range[i]
        if not (min_range <= r <= max_range):
            continue
        signal = min(max(reflectivity[i] * (0.35 + 0.65 * cos_incidence[i]), 0.0), 1.0)
        frac = r / max_range
        if rng.random() < dropout + far_dropout * frac * frac * (1.0 - signal):
            continue
        m = r + rng.normal(0.0, noise)
        scan[k, 0] = dirs[i, 0] * m
        scan[k, 1] = dirs[i, 1] * m
        scan[k, 2] = dirs[i, 2] * m
        gain = gains[i // per_beam]
        scan[k, 3] = min(max(gain * signal * math.exp(-r / falloff) + rng.normal(0.0, 0.02), 0.0), 1.0)
        label[k] = np.uint32(semantic[i]) | (np.uint32(instance[i]) << np.uint32(16))
        k += 1
    return scan[:k].copy(), label[:k].copy()
