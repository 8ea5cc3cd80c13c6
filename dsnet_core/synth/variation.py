"""Per-sequence choices: the street style, the LiDAR and how it is mounted and behaves (height,
pitch/roll, range noise, dropout, beam gains) and the materials' remission (per-class reflectivity,
global gain, range fall-off).

Everything is drawn from the sequence's own seed. The legacy default (the ``classic`` street with
``hdl64`` or ``vlp32``) draws nothing and keeps the presets, so its output stays byte-identical.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace

import numpy as np

from dsnet_core.errors import ConfigError
from dsnet_core.synth.raycast import GROUND_REFLECTIVITY
from dsnet_core.synth.scene import Scene
from dsnet_core.synth.sensor import LEGACY_SENSORS, SENSORS, LidarSpec, get_sensor
from dsnet_core.synth.styles import STYLES, check_style

MATERIAL_CLASSES = (10, 11, 13, 15, 18, 20, 30, 31, 32, 40, 44, 48, 49, 50, 51, 60, 70, 71, 72, 80, 81, 99)


@dataclass(frozen=True)
class SequenceSetup:
    """How one sequence is made.

    Attributes:
        style: street style name.
        sensor: LiDAR preset name.
        randomised: False only for the legacy default (presets untouched, nothing below drawn).
        spec: the effective LiDAR (mounting height, noise, dropout, gains as drawn).
        mount_pitch_deg, mount_roll_deg: the sensor's mounting tilt (degrees).
        material_gain: raw class -> reflectivity multiplier (empty: 1 for all).
    """

    style: str
    sensor: str
    randomised: bool
    spec: LidarSpec
    mount_pitch_deg: float = 0.0
    mount_roll_deg: float = 0.0
    material_gain: dict[int, float] | None = None

    def record(self) -> dict:
        """A JSON-able summary (written beside each sequence as ``synth.json``)."""
        spec = asdict(self.spec)
        spec.pop("elevations_deg")
        spec.pop("beam_gains")
        return {
            "style": self.style,
            "sensor": self.sensor,
            "randomised": self.randomised,
            "beams": self.spec.beams,
            "lidar": spec,
            "mount_pitch_deg": self.mount_pitch_deg,
            "mount_roll_deg": self.mount_roll_deg,
            "material_gain": {str(k): v for k, v in (self.material_gain or {}).items()},
        }

    def mount(self) -> np.ndarray:
        """``(4, 4) float64`` sensor → ego-mount rotation (pitch about y, then roll about x)."""
        p, r = np.deg2rad(self.mount_pitch_deg), np.deg2rad(self.mount_roll_deg)
        ry = np.array([[np.cos(p), 0, np.sin(p)], [0, 1, 0], [-np.sin(p), 0, np.cos(p)]])
        rx = np.array([[1, 0, 0], [0, np.cos(r), -np.sin(r)], [0, np.sin(r), np.cos(r)]])
        out = np.eye(4)
        out[:3, :3] = ry @ rx
        return out


def check_sensor(name: str) -> str:
    """``name`` if it is a sensor preset or ``random``.

    Raises:
        ConfigError: unknown name.
    """
    if name == "random":
        return name
    get_sensor(name)
    return name


def _pool(name: str, allowed: list[str] | tuple[str, ...] | None, known: list[str], what: str) -> list[str]:
    pool = list(allowed) if allowed else known
    bad = [p for p in pool if p not in known]
    if bad or not pool:
        raise ConfigError(f"unknown {what} {bad} in the {what} list; known: {sorted(known)}")
    return pool


def choose_setup(
    seed: np.random.SeedSequence,
    style: str = "classic",
    sensor: str = "hdl64",
    styles: list[str] | tuple[str, ...] | None = None,
    sensors: list[str] | tuple[str, ...] | None = None,
) -> SequenceSetup:
    """Resolve ``random`` (drawn from ``styles``/``sensors``, default all) and draw the sensor's
    mounting, noise and the remission model for any sequence other than the legacy default.

    Raises:
        ConfigError: an unknown style or sensor.
    """
    check_style(style)
    check_sensor(sensor)
    if style == "classic" and sensor in LEGACY_SENSORS:
        return SequenceSetup(style, sensor, False, get_sensor(sensor))
    rng = np.random.default_rng(seed)
    if style == "random":
        pool = _pool(style, styles, list(STYLES), "style")
        style = pool[int(rng.integers(len(pool)))]
    if sensor == "random":
        pool = _pool(sensor, sensors, list(SENSORS), "sensor")
        sensor = pool[int(rng.integers(len(pool)))]
    base = get_sensor(sensor)
    gains = np.asarray(base.beam_gains or (1.0,) * base.beams) * rng.uniform(0.85, 1.15, base.beams)
    spec = replace(
        base,
        height=float(rng.uniform(1.5, 2.2)),
        range_noise=float(base.range_noise * rng.uniform(0.5, 2.0)),
        dropout=float(rng.uniform(0.0, 0.1)),
        far_dropout=float(rng.uniform(0.3, 0.9)),
        beam_gains=tuple(float(g) for g in gains),
        remission_gain=float(rng.uniform(0.6, 1.5)),
        falloff=float(rng.uniform(120.0, 400.0)),
    )
    material = {
        c: float(g)
        for c, g in zip(MATERIAL_CLASSES, rng.uniform(0.6, 1.5, len(MATERIAL_CLASSES)), strict=True)
    }
    return SequenceSetup(
        style,
        sensor,
        True,
        spec,
        float(rng.uniform(-2.0, 2.0)),
        float(rng.uniform(-1.5, 1.5)),
        material,
    )


def apply_materials(scene: Scene, setup: SequenceSetup) -> Scene:
    """The scene with every reflectivity scaled by its class's drawn gain (clipped to [0, 1])."""
    if not setup.material_gain:
        return scene
    table = np.ones(1 << 9)
    for c, g in setup.material_gain.items():
        table[c] = g
    moving = {252: 10, 253: 31, 254: 30, 255: 32, 256: 16, 257: 13, 258: 18, 259: 20}
    for m, c in moving.items():
        table[m] = table[c]

    def scaled(p):
        return replace(p, reflectivity=np.clip(p.reflectivity * table[p.semantic], 0.0, 1.0))

    ground = np.clip(GROUND_REFLECTIVITY * table[: GROUND_REFLECTIVITY.size], 0.0, 1.0)
    actors = replace(scene.actors, parts=scaled(scene.actors.parts))
    return replace(scene, static=scaled(scene.static), actors=actors, ground_reflectivity=ground)
