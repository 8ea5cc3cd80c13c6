"""One sequence's world: road, ground layout, static primitives, moving actors and the ego's lane.

``build_scene`` composes the street (``layout``) and its things (``traffic``). Near the ego's start
it always places one of each thing class in plain view, so every class appears in a short log.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dsnet_core.synth.config import SynthConfig
from dsnet_core.synth.layout import SIDES, Occupancy, Street, StuffPlacer, make_layout
from dsnet_core.synth.primitives import PrimitiveSet
from dsnet_core.synth.road import LAWN_END, PARKING_END, ROAD_EDGE, SIDEWALK_END, GroundLayout, Road
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
        ego_speed: m/s.
        things: instance id -> (raw SemanticKITTI id, moving).
    """

    road: Road
    layout: GroundLayout
    static: PrimitiveSet
    actors: Actors
    ego_d: float
    ego_speed: float
    things: dict[int, tuple[int, bool]]

    def primitives_at(self, t: float) -> PrimitiveSet:
        """All world primitives at time ``t`` (seconds)."""
        return PrimitiveSet.concat([self.static, self.actors.at(self.road, t)])


def build_scene(rng: np.random.Generator, duration: float, config: SynthConfig) -> Scene:
    """Draw a street around an ego drive of ``duration`` seconds."""
    ego_speed = float(rng.uniform(*config.ego_speed))
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
    speeds = {ego_lane: ego_speed}
    lane_speed = {-(m - 0.5) * lane_w: speeds.get(m, rng.uniform(6.0, 15.0)) for m in range(1, lanes + 1)}
    lane_speed.update({(m - 0.5) * lane_w: -rng.uniform(6.0, 15.0) for m in range(1, lanes + 1)})
    bike_d = {sign: sign * (lay.edge(side, ROAD_EDGE, 0.0) - 0.75) for side, sign in enumerate(SIDES)}
    bike_speed = {sign: -sign * rng.uniform(3.5, 6.5) for sign in SIDES}
    traffic.reserve(ego_d, -8.0, 8.0)

    _guaranteed(rng, traffic, street, ego_d, ego_speed, lane_speed, bike_d, bike_speed)
    traffic.park_street(config.parked)
    traffic.sidewalk_things(s_lo, s_hi)

    def window(speed: float) -> tuple[float, float]:
        # start positions from which an actor comes within ``reach`` of the ego during the drive
        rel = (speed - ego_speed) * duration
        return -reach - max(0.0, rel), reach + max(0.0, -rel)

    def vehicle():
        return [CAR, TRUCK, BUS, OTHER_VEHICLE, MOTORCYCLIST][rng.choice(5, p=[0.86, 0.03, 0.02, 0.03, 0.06])]

    dense = 1.0 / max(config.traffic, 1e-3)
    for d, speed in lane_speed.items():
        traffic.fill_lane(d, speed, *window(speed), (15.0 * dense, 90.0 * dense), vehicle)
    for sign in SIDES:
        traffic.fill_lane(
            bike_d[sign],
            bike_speed[sign],
            *window(bike_speed[sign]),
            (40.0 * dense, 200.0 * dense),
            lambda: BICYCLIST,
        )
    walk = 1.0 / max(config.pedestrians, 1e-3)
    for side, sign in enumerate(SIDES):
        curb, outer = lay.edge(side, LAWN_END, 0.0), lay.edge(side, SIDEWALK_END, 0.0)
        for frac, direction in ((0.4, 1.0), (0.62, -1.0)):
            speed = direction * rng.uniform(0.8, 1.6)
            d = sign * (curb + frac * (outer - curb))
            traffic.fill_lane(d, speed, *window(speed), (6.0 * walk, 60.0 * walk), lambda: PERSON)

    placer = StuffPlacer(rng, road, street, occ)
    static = PrimitiveSet.concat([traffic.static(), placer.run().build()])
    return Scene(road, lay, static, traffic.actors(), ego_d, ego_speed, traffic.things)


def _guaranteed(
    rng, traffic: Traffic, street: Street, ego_d, ego_speed, lane_speed, bike_d, bike_speed
) -> None:
    """One of each thing class within ~50 m ahead of the ego's start, where it can be seen."""
    lay = street.layout
    right, left = 1, 0
    sw = lay.edge(right, SIDEWALK_END, 12.0)
    sw_left = lay.edge(left, SIDEWALK_END, 12.0)
    s = rng.uniform(9.0, 12.0)
    for _ in range(3):
        traffic.park(BICYCLE, s, -(sw - 0.35), rng.normal(0, 0.1))
        s += rng.uniform(2.0, 2.6)
    traffic.park(PERSON, rng.uniform(17.0, 22.0), -(sw - 0.35), rng.uniform(0, 2 * np.pi))
    traffic.park(MOTORCYCLE, rng.uniform(12.0, 18.0), sw_left - 0.5, np.pi + rng.normal(0, 0.1))
    traffic.drive(BICYCLIST, rng.uniform(14.0, 22.0), bike_d[-1.0], bike_speed[-1.0])
    traffic.drive(CAR, rng.uniform(18.0, 26.0), ego_d, ego_speed)
    opposite = min(d for d in lane_speed if d > 0)
    s = rng.uniform(15.0, 25.0)
    unplaced = [TRUCK, OTHER_VEHICLE]
    if street.ensure_parking(left, 20.0, 60.0):  # a delivery truck and a van parked across the road
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
        traffic.drive(cls, s, opposite, lane_speed[opposite], shape)
        s += shape.length / 2 + rng.uniform(6.0, 15.0)
    traffic.drive(
        PERSON,
        rng.uniform(5.0, 15.0),
        (lay.edge(left, LAWN_END, 10.0) + lay.edge(left, SIDEWALK_END, 10.0)) / 2,
        -1.2,
    )
