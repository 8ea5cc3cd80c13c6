"""Spinning multi-beam LiDAR models: beam layout, and how a geometric hit becomes a return
(range noise, dropout, remission from material and incidence angle)."""

from __future__ import annotations

from dataclasses import dataclass

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

    @property
    def beams(self) -> int:
        return len(self.elevations_deg)

    @property
    def rays(self) -> int:
        return self.beams * self.azimuth_steps

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


SENSORS: dict[str, LidarSpec] = {
    "hdl64": LidarSpec("hdl64", _hdl64_elevations(), azimuth_steps=2048, max_range=120.0),
    "vlp32": LidarSpec("vlp32", _vlp32_elevations(), azimuth_steps=1024, max_range=100.0),
}


def get_sensor(name: str) -> LidarSpec:
    """The preset called ``name`` (``hdl64`` or ``vlp32``).

    Raises:
        ConfigError: unknown name.
    """
    try:
        return SENSORS[name]
    except KeyError:
        raise ConfigError(f"unknown LiDAR model {name!r}; known: {sorted(SENSORS)}") from None


def simulate_returns(
    spec: LidarSpec,
    hit_range: np.ndarray,
    cos_incidence: np.ndarray,
    reflectivity: np.ndarray,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Turn geometric hits into sensor returns.

    Args:
        hit_range: ``(R,) float64`` distance to the first surface along each ray (inf: no hit), metres.
        cos_incidence: ``(R,) float64`` |cos| of the angle between ray and surface normal.
        reflectivity: ``(R,) float64`` material reflectivity in [0, 1].

    Returns:
        ``keep`` ``(R,) bool`` rays that produce a point, ``range`` ``(R,) float64`` measured range
        (metres, with noise), ``remission`` ``(R,) float32`` in [0, 1].
    """
    n = hit_range.shape[0]
    u = rng.random(n)
    noise = rng.normal(0.0, spec.range_noise, n)
    rem_noise = rng.normal(0.0, 0.02, n)
    hit = np.isfinite(hit_range) & (hit_range >= spec.min_range) & (hit_range <= spec.max_range)
    r = np.where(hit, hit_range, spec.max_range)
    frac = r / spec.max_range
    signal = reflectivity * (0.35 + 0.65 * cos_incidence)
    p_drop = spec.dropout + spec.far_dropout * frac**2 * (1.0 - np.clip(signal, 0.0, 1.0))
    keep = hit & (u >= p_drop)
    remission = np.clip(signal * np.exp(-r / 250.0) + rem_noise, 0.0, 1.0).astype(np.float32)
    return keep, r + noise, remission
