"""Things: parked vehicles, bicycles and standing people (static), and moving traffic (actors that
follow lanes at constant speed). Every thing gets its own instance id, kept over the whole log."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from dsnet_core.synth import templates
from dsnet_core.synth.layout import SIDES, Occupancy, Street
from dsnet_core.synth.primitives import PrimitiveBuilder, PrimitiveSet
from dsnet_core.synth.road import PARKING_END, ROAD_EDGE, SIDEWALK_END, Road

# raw SemanticKITTI ids: (static, moving)
CAR, BICYCLE, BUS, MOTORCYCLE, TRUCK, OTHER_VEHICLE = (
    (10, 252),
    (11, 11),
    (13, 257),
    (15, 15),
    (18, 258),
    (20, 259),
)
PERSON, BICYCLIST, MOTORCYCLIST = (30, 254), (31, 253), (32, 255)

SHAPES: dict[tuple[int, int], Callable[[np.random.Generator], templates.Shape]] = {
    CAR: templates.car,
    BICYCLE: templates.bicycle,
    BUS: templates.bus,
    MOTORCYCLE: templates.motorcycle,
    TRUCK: templates.truck,
    OTHER_VEHICLE: templates.van_or_trailer,
    PERSON: templates.person,
    BICYCLIST: templates.bicyclist,
    MOTORCYCLIST: templates.motorcyclist,
}


@dataclass(frozen=True)
class Actors:
    """Moving objects: parts in the actor frame plus a lane-following trajectory per actor.

    Attributes:
        parts: part primitives with ``center``/``yaw`` relative to the actor frame.
        owner: ``(Q,) int64`` actor index of each part.
        s0: ``(A,)`` arc length at t = 0 (metres).
        d: ``(A,)`` lateral offset (metres, left positive).
        speed: ``(A,)`` signed speed along s (m/s); negative drives against increasing s.
    """

    parts: PrimitiveSet
    owner: np.ndarray
    s0: np.ndarray
    d: np.ndarray
    speed: np.ndarray

    def at(self, road: Road, t: float) -> PrimitiveSet:
        """World primitives of all actors at time ``t`` (seconds)."""
        if not len(self.parts):
            return self.parts
        x, y, h = road.pose_at(self.s0 + self.speed * t, self.d)
        h = h + np.where(self.speed < 0, np.pi, 0.0)
        o = self.owner
        c, s = np.cos(h[o]), np.sin(h[o])
        lc = self.parts.center
        center = np.stack(
            [x[o] + c * lc[:, 0] - s * lc[:, 1], y[o] + s * lc[:, 0] + c * lc[:, 1], lc[:, 2]], axis=1
        )
        p = self.parts
        return PrimitiveSet(p.kind, center, p.yaw + h[o], p.half, p.semantic, p.instance, p.reflectivity)


@dataclass
class Traffic:
    """Builds the things of a street: :meth:`park` and :meth:`drive` place one (lanes and footprints
    keep them apart), :meth:`fill_lane`, :meth:`park_street` and :meth:`sidewalk_things` populate;
    :meth:`static` and :meth:`actors` return the result."""

    rng: np.random.Generator
    road: Road
    street: Street
    occ: Occupancy
    next_instance: int = 1
    _static: PrimitiveBuilder = field(default_factory=PrimitiveBuilder)
    _parts: PrimitiveBuilder = field(default_factory=PrimitiveBuilder)
    _owner: list[int] = field(default_factory=list)
    _traj: list[tuple[float, float, float]] = field(default_factory=list)
    _lane_busy: dict[float, list[tuple[float, float]]] = field(default_factory=dict)
    things: dict[int, tuple[int, bool]] = field(default_factory=dict)  # instance -> (raw id, moving)
    shapes: dict[tuple[int, int], Callable[[np.random.Generator], templates.Shape]] = field(
        default_factory=lambda: dict(SHAPES)
    )  # the templates a street draws its things from (styles swap in richer ones)

    def _new_instance(self, raw: int, moving: bool) -> int:
        inst = self.next_instance
        self.next_instance += 1
        self.things[inst] = (raw, moving)
        return inst

    def park(self, cls: tuple[int, int], s: float, d: float, yaw_offset: float = 0.0, shape=None) -> bool:
        """Place a static thing at Frenet ``(s, d)``; False if the spot is taken."""
        shape = shape or self.shapes[cls](self.rng)
        margin = 0.15 if shape.length > 2.5 else 0.04
        if not self.occ.take_box(s, d, shape.length, shape.width, yaw_offset, margin):
            return False
        x, y, h = self.road.pose_at(s, d)
        self._static.add_parts(
            shape.parts, float(x), float(y), float(h) + yaw_offset, cls[0], self._new_instance(cls[0], False)
        )
        return True

    def drive(
        self, cls: tuple[int, int], s0: float, d: float, speed: float, shape=None, group: int = 1
    ) -> bool:
        """Add a moving actor on the lane at offset ``d`` (all actors of a lane share its speed);
        ``group`` > 1 puts that many side by side (people walking together)."""
        shapes = [shape or self.shapes[cls](self.rng)] + [
            self.shapes[cls](self.rng) for _ in range(group - 1)
        ]
        length = max(s.length for s in shapes)
        busy = self._lane_busy.setdefault(round(d, 3), [])
        lo, hi = s0 - length / 2 - 1.0, s0 + length / 2 + 1.0
        if any(lo < b and a < hi for a, b in busy):
            return False
        busy.append((lo, hi))
        width = 0.6 if group > 1 else 0.0
        for k, sh in enumerate(shapes):
            actor = len(self._traj)
            lateral = (k - (group - 1) / 2) * width
            self._traj.append(
                (s0 + (self.rng.uniform(-0.25, 0.25) if group > 1 else 0.0), d + lateral, speed)
            )
            inst = self._new_instance(cls[1], True)
            self._parts.add_parts(sh.parts, 0.0, 0.0, 0.0, cls[1], inst)
            self._owner.extend([actor] * len(sh.parts))
        return True

    def reserve(self, d: float, lo: float, hi: float) -> None:
        """Keep ``[lo, hi]`` (at t = 0) of the lane at ``d`` free (the ego's own place)."""
        self._lane_busy.setdefault(round(d, 3), []).append((lo, hi))

    def fill_lane(
        self,
        d: float,
        speed: float,
        lo: float,
        hi: float,
        gap: tuple[float, float],
        choose,
        pairs: float = 0.0,
    ) -> None:
        """Spawn actors along ``[lo, hi]`` with random gaps; ``choose()`` returns a class; a share
        ``pairs`` of them walk in pairs."""
        s = lo + self.rng.uniform(0.0, gap[1])
        while s < hi:
            self.drive(choose(), s, d, speed, group=2 if self.rng.random() < pairs else 1)
            s += self.rng.uniform(*gap)

    def park_street(self, parked: float) -> None:
        """Fill parking strips with vehicles (and the odd motorcycle) and paved lots with cars."""
        rng, lay = self.rng, self.street.layout
        for side, s0, s1 in self.street.parking:
            sign = SIDES[side]
            s = s0 + rng.uniform(0.5, 3.0)
            while s < s1 - 3.0:
                cls = [CAR, OTHER_VEHICLE, TRUCK, MOTORCYCLE][rng.choice(4, p=[0.84, 0.06, 0.04, 0.06])]
                shape = self.shapes[cls](rng)
                sc = s + shape.length / 2
                if sc + shape.length / 2 > s1:
                    break
                d = sign * (lay.edge(side, ROAD_EDGE, sc) + lay.edge(side, PARKING_END, sc)) / 2
                if rng.random() < parked:
                    self.park(cls, sc, d, 0.0 if sign < 0 else np.pi, shape)
                s = sc + shape.length / 2 + rng.uniform(0.6, 2.5)
        for lot in self.street.lots:
            if lot.kind != "paved" or rng.random() < 0.4:  # some paved lots are empty forecourts
                continue
            sign = SIDES[lot.side]
            base = lay.edge(lot.side, SIDEWALK_END, (lot.s0 + lot.s1) / 2)
            for s in np.arange(lot.s0 + 1.5, lot.s1 - 1.5, 2.8):
                if rng.random() < parked * 0.6:
                    self.park(
                        CAR, float(s), sign * (base + rng.uniform(4.0, 6.0)), np.pi / 2 + rng.normal(0, 0.05)
                    )

    def sidewalk_things(self, s_lo: float, s_hi: float) -> None:
        """Parked bicycles and standing people on the sidewalks; bike racks and groups of people on
        the raised kerbside bays."""
        rng, lay = self.rng, self.street.layout
        for side, sign in enumerate(SIDES):
            d = sign * (lay.edge(side, ROAD_EDGE, 0.0) + lay.edge(side, PARKING_END, 0.0)) / 2
            for a, b in self.street.bulb_outs(side):
                if b < s_lo or a > s_hi or rng.random() < 0.4:
                    continue
                s = rng.uniform(a + 0.5, max(a + 0.5, b - 4.0))
                if rng.random() < 0.6:  # a bike rack: bicycles side by side, 0.7-0.9 m apart
                    for _ in range(int(rng.integers(2, 8))):
                        if s > b - 0.4:
                            break
                        self.park(BICYCLE, s, d, np.pi / 2 + rng.normal(0, 0.03))
                        s += rng.uniform(0.75, 0.9)
                else:  # people standing together
                    for k in range(int(rng.integers(2, 5))):
                        ang = 2 * np.pi * k / 4 + rng.normal(0, 0.2)
                        self.park(PERSON, s + 0.65 * np.cos(ang), d + 0.6 * np.sin(ang), ang + np.pi)
            s = s_lo + rng.uniform(0.0, 20.0)
            while s < s_hi:
                outer = lay.edge(side, SIDEWALK_END, s)
                if rng.random() < 0.5:
                    for k in range(int(rng.integers(1, 5))):
                        self.park(BICYCLE, s + 2.2 * k, sign * (outer - 0.35), rng.normal(0, 0.1))
                else:
                    self.park(PERSON, s, sign * (outer - 0.35), rng.uniform(0, 2 * np.pi))
                s += rng.uniform(15.0, 50.0)

    def static(self) -> PrimitiveSet:
        return self._static.build()

    def actors(self) -> Actors:
        traj = np.asarray(self._traj, dtype=np.float64).reshape(-1, 3)
        return Actors(
            self._parts.build(), np.asarray(self._owner, np.int64), traj[:, 0], traj[:, 1], traj[:, 2]
        )
