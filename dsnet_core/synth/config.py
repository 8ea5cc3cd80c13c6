"""Configuration of the synthetic driving-log generator."""

from __future__ import annotations

from dataclasses import dataclass, field

from dsnet_core.errors import ConfigError

VARIETIES = ("base", "wide")


@dataclass(frozen=True)
class SynthConfig:
    """Knobs of the procedural world and the ego drive (all lengths in metres, speeds in m/s).

    Attributes:
        sensor: LiDAR preset (``hdl64`` or ``vlp32``).
        frame_period: seconds between scans (10 Hz spin).
        ego_speed: (min, max) ego speed, drawn once per sequence.
        min_curve_radius: tightest road curvature radius.
        view_radius: the world is built this far around the ego path.
        traffic: multiplier on the density of moving vehicles.
        pedestrians: multiplier on the density of walking people.
        parked: probability that a parking slot holds a vehicle.
        jitter_deg: amplitude of the ego's pitch/roll oscillation (degrees).
        variety: how widely the street styles randomise what the world varies and the styles held
            fixed (:data:`VARIETIES`): ``base``, or ``wide`` (:mod:`dsnet_core.synth.styles.wide`:
            textured and low buildings, fences and walls of any height and porosity, bark, people
            by trees and on grass, rough and undulating grass, patchy remission, flush or jagged
            road edges, vans as cars). The classic street ignores it (its output is pinned).
    """

    sensor: str = "hdl64"
    frame_period: float = 0.1
    ego_speed: tuple[float, float] = (7.0, 12.0)
    min_curve_radius: float = 70.0
    view_radius: float = 130.0
    traffic: float = 1.0
    pedestrians: float = 1.0
    parked: float = 0.65
    jitter_deg: float = 0.3
    variety: str = field(default="base", repr=False)  # not in repr: base streams keep their fingerprints

    def __post_init__(self) -> None:
        if self.variety not in VARIETIES:
            raise ConfigError(f"unknown synth variety {self.variety!r}; choose {' or '.join(VARIETIES)}")
