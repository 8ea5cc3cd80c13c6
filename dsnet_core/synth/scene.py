"""One sequence's world: road, ground layout, static primitives, moving actors and the ego's lane.

``build_scene`` composes the street (``layout``) and its things (``traffic``). Near the ego's start
it always places one of each thing class in plain view, so every class appears in a short log.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from dsnet_core.synth.config import SynthConfig
from dsnet_core.synth.ground import RasterGround
from dsnet_core.synth.layout import SIDES, SIDEWALK_BAND, Occupancy, Street, StuffPlacer, make_layout
from dsnet_core.synth.primitives import PrimitiveSet
from dsnet_core.synth.road import (
    LAWN_END,
    PARKING,
    PARKING_END,
    ROAD_EDGE,
    SIDEWALK,
    SIDEWALK_END,
    GroundLayout,
    Road,
)
from dsnet_core.synth.surface import Surface
from dsnet_core.synth.traffic import (
    BICYCLE,
    BICYCLIST,
    BUS,
    CAR,
    MOTORCYCLE,
    MOTORCYCLIST,
    OTHER_VEHICLE,
    PERSON,
    SHAPES,
    TRUCK,
    Actors,
    Traffic,
)


@dataclass(frozen=True)
class Scene:
    """A world in which the ego drives from s = 0 along the lane at ``ego_d`` at ``ego_speed``.

    Attributes:
        road: centre line.
        layout: ground classes.
        static: world primitives that never move (stuff and parked things).
        actors: moving things.
        ego_d: the ego lane's lateral offset (metres).
        ego_speed: mean speed (m/s).
        things: instance id -> (raw SemanticKITTI id, moving).
        ego_surge: (amplitude m/s, period s, phase rad) of the ego's speed oscillation.
        ground: painted ground of a styled street (None: the classic flat street of ``layout``).
        ground_reflectivity: ``(256,) float64`` reflectivity per raw ground class (None: the
            defaults of :data:`raycast.GROUND_REFLECTIVITY`).
        style: the street style that built this scene.
        surface: ground detail of the ``wide`` variety (rough grass, patchy remission; None: none).
    """

    road: Road
    layout: GroundLayout
    static: PrimitiveSet
    actors: Actors
    ego_d: float
    ego_speed: float
    things: dict[int, tuple[int, bool]]
    ego_surge: tuple[float, float, float] = (0.0, 1.0, 0.0)
    ground: RasterGround | None = None
    ground_reflectivity: np.ndarray | None = None
    style: str = "classic"
    surface: Surface | None = None

    def ego_s(self, t: np.ndarray) -> np.ndarray:
        """Arc length of the ego at times ``t`` (s): mean speed plus a slow surge, so the drive
        speeds up and slows down; it stays within ``2 · amplitude · period / 2π`` of uniform motion."""
        amp, period, phase = self.ego_surge
        w = 2 * np.pi / period
        return self.ego_speed * t + amp / w * (np.sin(w * t + phase) - np.sin(phase))

    def primitives_at(self, t: float) -> PrimitiveSet:
        """All world primitives at time ``t`` (seconds)."""
        actors = self.actors.at(self.road, t)
        if self.ground is not None and len(actors):
            x, y, _ = self.road.pose_at(self.actors.s0 + self.actors.speed * t, self.actors.d)
            lift = self.ground.height_at(x, y)[self.actors.owner]
            actors = replace(actors, center=actors.center + np.stack([0 * lift, 0 * lift, lift], axis=1))
        return PrimitiveSet.concat([self.static, actors])


def build_scene(rng: np.random.Generator, duration: float, config: SynthConfig) -> Scene:
    """Draw a street around an ego drive of ``duration`` seconds."""
    ego_speed = float(rng.uniform(*config.ego_speed))
    surge = (float(rng.uniform(0.0, 1.0)), float(rng.uniform(15.0, 30.0)), float(rng.uniform(0, 2 * np.pi)))
    slack = 2 * surge[0] * surge[1] / (2 * np.pi)  # how far the surge moves the ego off uniform motion
    reach = config.view_radius
    s_lo, s_hi = -reach - 20.0, ego_speed * duration + reach + 20.0
    road = Road.generate(rng, s_lo - 400.0, s_hi + 400.0, config.min_curve_radius)
    street = make_layout(rng, s_lo, s_hi)
    lay = street.layout
    occ = Occupancy()
    traffic = Traffic(rng, road, street, occ)

    lanes, lane_w = lay.lanes, lay.lane_width
    ego_lane = int(rng.integers(1, lanes + 1))
    ego_d = -(ego_lane - 0.5) * lane_w
    # every lane: (lateral offset, signed speed); actors of one lane share its speed, so never collide
    roads = {
        -(m - 0.5) * lane_w: ego_speed if m == ego_lane else rng.uniform(6.0, 15.0)
        for m in range(1, lanes + 1)
    }
    roads.update({(m - 0.5) * lane_w: -rng.uniform(6.0, 15.0) for m in range(1, lanes + 1)})
    bikes = {
        sign: (sign * (lanes * lane_w + lay.edge(side, ROAD_EDGE, 0.0)) / 2, -sign * rng.uniform(3.5, 6.5))
        for side, sign in enumerate(SIDES)
    }
    walks = {}  # (sign, k) -> (d, speed, share walking in pairs)
    for side, sign in enumerate(SIDES):
        # people walk on the inner part of the sidewalk; its outer SIDEWALK_BAND holds parked things
        curb, outer = lay.edge(side, LAWN_END, 0.0), lay.edge(side, SIDEWALK_END, 0.0) - SIDEWALK_BAND
        pairs = 0.35 if outer - curb >= 2.4 else 0.0
        for k, (frac, direction) in enumerate(((0.3, 1.0), (0.75, -1.0))):
            walks[sign, k] = (
                sign * (curb + frac * (outer - curb)),
                direction * rng.uniform(0.8, 1.6),
                pairs * (k == 0),
            )
    traffic.reserve(ego_d, -8.0 - slack, 8.0 + slack)

    _guaranteed(rng, traffic, street, ego_d, ego_speed, roads, bikes, walks)
    traffic.park_street(config.parked)
    traffic.sidewalk_things(s_lo, s_hi)

    def window(speed: float) -> tuple[float, float]:
        # start positions from which an actor comes within ``reach`` of the ego during the drive
        rel = (speed - ego_speed) * duration
        return -reach - max(0.0, rel) - slack, reach + max(0.0, -rel) + slack

    def vehicle():
        return [CAR, TRUCK, BUS, OTHER_VEHICLE, MOTORCYCLIST][rng.choice(5, p=[0.86, 0.03, 0.02, 0.03, 0.06])]

    dense = 1.0 / max(config.traffic, 1e-3)
    for d, speed in roads.items():
        traffic.fill_lane(d, speed, *window(speed), (15.0 * dense, 90.0 * dense), vehicle)
    for d, speed in bikes.values():
        traffic.fill_lane(d, speed, *window(speed), (40.0 * dense, 200.0 * dense), lambda: BICYCLIST)
    walk = 1.0 / max(config.pedestrians, 1e-3)
    for d, speed, pairs in walks.values():
        traffic.fill_lane(d, speed, *window(speed), (6.0 * walk, 60.0 * walk), lambda: PERSON, pairs)

    placer = StuffPlacer(rng, road, street, occ)
    static = PrimitiveSet.concat([traffic.static(), placer.run().build()])
    return Scene(road, lay, static, traffic.actors(), ego_d, ego_speed, traffic.things, surge)


def _guaranteed(rng, traffic: Traffic, street: Street, ego_d, ego_speed, roads, bikes, walks) -> None:
    """One of each thing class within ~50 m ahead of the ego's start, where it can be seen."""
    lay = street.layout
    right, left = 1, 0
    sw = lay.edge(right, SIDEWALK_END, 12.0)
    kerb = {side: (lay.edge(side, ROAD_EDGE, 0.0) + lay.edge(side, PARKING_END, 0.0)) / 2 for side in (0, 1)}
    s = rng.uniform(9.0, 12.0)
    if street.set_kerb(right, s - 1.0, s + 4.0, SIDEWALK):  # a bike rack on a bay by the road
        for _ in range(3):
            traffic.park(BICYCLE, s, -kerb[right], np.pi / 2 + rng.normal(0, 0.03))
            s += rng.uniform(0.8, 1.0)
    else:
        for _ in range(3):
            traffic.park(BICYCLE, s, -(sw - 0.35), rng.normal(0, 0.1))
            s += rng.uniform(2.0, 2.6)
    traffic.park(PERSON, rng.uniform(17.0, 22.0), -(sw - 0.35), rng.uniform(0, 2 * np.pi))
    s = rng.uniform(15.0, 18.0)  # a motorcycle parked at the kerb, near side if it has a strip
    for side in (right, left):
        if street.set_kerb(side, s - 1.5, s + 1.5, PARKING):
            traffic.park(
                MOTORCYCLE, s, SIDES[side] * kerb[side], (0.0, np.pi)[side == left] + rng.normal(0, 0.05)
            )
            break
    else:  # no kerbside strip: on the sidewalk, past the bikes and the person
        traffic.park(MOTORCYCLE, s + 10.0, -(sw - 0.45), rng.normal(0, 0.05))
    street.set_kerb(left, 20.0, 60.0, PARKING)  # a truck and a van parked across the road (if a strip)
    traffic.drive(BICYCLIST, rng.uniform(14.0, 22.0), *bikes[-1.0])
    traffic.drive(CAR, rng.uniform(22.0, 30.0), ego_d, ego_speed)
    opposite = min(d for d in roads if d > 0)
    s = rng.uniform(15.0, 25.0)
    unplaced = [TRUCK, OTHER_VEHICLE]
    if lay.classes[left, 0, lay.bin(30.0)] == PARKING:
        s_park = rng.uniform(22.0, 26.0)
        d = (lay.edge(left, ROAD_EDGE, s_park) + lay.edge(left, PARKING_END, s_park)) / 2
        for cls in [TRUCK, OTHER_VEHICLE]:
            shape = SHAPES[cls](rng)
            if traffic.park(cls, s_park + shape.length / 2, d, np.pi, shape):
                unplaced.remove(cls)
            s_park += shape.length + rng.uniform(1.0, 3.0)
    for cls in [MOTORCYCLIST, *unplaced, CAR]:  # what could not park drives towards the ego
        shape = SHAPES[cls](rng)
        s += shape.length / 2
        traffic.drive(cls, s, opposite, roads[opposite], shape)
        s += shape.length / 2 + rng.uniform(6.0, 15.0)
    d, speed, _ = walks[1.0, 1]  # the left sidewalk's lane walking towards the ego
    traffic.drive(PERSON, rng.uniform(5.0, 15.0), d, speed)
