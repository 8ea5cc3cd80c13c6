"""What every street style shares: a cross-section (carriageway, kerbside strip, verge, sidewalk),
the painted raster ground under a graded, crowned surface, traffic lanes, and lifting every object
onto the ground. A style is a :class:`StreetStyle` subclass that sets its ranges and overrides a few
hooks (``section``, ``kerbside``, ``lots``, ``paint``, ``populate``)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from dsnet_core.synth import shapes, templates
from dsnet_core.synth.config import SynthConfig
from dsnet_core.synth.ground import (
    Canvas,
    RasterGround,
    finish,
    grade_profile,
    make_canvas,
    street_height,
)
from dsnet_core.synth.layout import (
    SIDES,
    SIDEWALK_BAND,
    TRUNK,
    VEGETATION,
    Lot,
    Occupancy,
    Street,
    StuffPlacer,
    _runs,
)
from dsnet_core.synth.primitives import ELLIPSOID, PrimitiveSet
from dsnet_core.synth.road import (
    DASH_ON,
    DASH_PERIOD,
    LANE_MARKING,
    PARKING,
    ROAD,
    SIDEWALK,
    TERRAIN,
    GroundLayout,
    Road,
)
from dsnet_core.synth.scene import Scene
from dsnet_core.synth.traffic import (
    BICYCLE,
    BICYCLIST,
    BUS,
    CAR,
    MOTORCYCLE,
    MOTORCYCLIST,
    OTHER_VEHICLE,
    PERSON,
    TRUCK,
    Traffic,
)

STYLE_SHAPES = {
    CAR: shapes.any_car,
    BICYCLE: templates.bicycle,
    BUS: shapes.city_bus,
    MOTORCYCLE: shapes.two_wheeler,
    TRUCK: shapes.any_truck,
    OTHER_VEHICLE: shapes.van,
    PERSON: shapes.person,
    BICYCLIST: templates.bicyclist,
    MOTORCYCLIST: templates.motorcyclist,
}


@dataclass(frozen=True)
class Section:
    """A street's cross-section, per side (0 left, 1 right), widths in metres.

    Attributes:
        lanes: traffic lanes per side.
        lane_width: metres.
        median: full width of a raised central median (0: none).
        median_class: raw class of the median (terrain: grass, sidewalk: paved island).
        bike: bike-lane width per side behind a solid line (0: none).
        widths: ``(2, 3)`` kerbside strip, verge (grass), sidewalk widths per side.
        road_class: raw class of the carriageway (road; parking in a parking lot).
        markings: paint lane markings.
        flush_kerbside: the kerbside strip is level with the road whatever its class (gravel).
    """

    lanes: int
    lane_width: float
    median: float = 0.0
    median_class: int = TERRAIN
    bike: float = 0.0
    widths: tuple[tuple[float, float, float], tuple[float, float, float]] = ((0, 0, 2.0), (0, 0, 2.0))
    road_class: int = ROAD
    markings: bool = True
    flush_kerbside: bool = False

    @property
    def carriageway(self) -> float:
        """|d| of the kerb line (metres)."""
        return self.median / 2 + self.lanes * self.lane_width + self.bike

    def edges(self, side: int) -> np.ndarray:
        """``(4,)`` |d| of road edge, kerbside end, verge end, sidewalk end."""
        return np.cumsum([self.carriageway, *self.widths[side]])

    def lane_centres(self) -> list[float]:
        """|d| of the centre of each lane, inner first."""
        return [self.median / 2 + (m - 0.5) * self.lane_width for m in range(1, self.lanes + 1)]


@dataclass
class Ctx:
    """Everything a style's ``populate`` works with."""

    rng: np.random.Generator
    config: SynthConfig
    road: Road
    street: Street
    section: Section
    ground: RasterGround
    occ: Occupancy
    traffic: Traffic
    ego_speed: float
    slack: float
    duration: float
    s_lo: float
    s_hi: float
    stuff: list[PrimitiveSet] = field(default_factory=list)
    ego_d: float = 0.0

    def window(self, speed: float) -> tuple[float, float]:
        """Start positions from which an actor at ``speed`` comes within view during the drive."""
        reach = self.config.view_radius
        rel = (speed - self.ego_speed) * self.duration
        return -reach - max(0.0, rel) - self.slack, reach + max(0.0, -rel) + self.slack

    def ground_class(self, s: float, d: float) -> int:
        x, y, _ = self.road.pose_at(s, d)
        i, j = self.ground.cell(x, y)
        return int(self.ground.cls[i, j])


class StylePlacer(StuffPlacer):
    """The classic stuff placer with varied trees (crown shapes and porosity)."""

    crown: str | None = None  # one species for a street's tree rows (None: mixed)

    def tree(self, s: float, d: float, crown: str | None = None) -> None:
        trunk, crown_parts = shapes.tree(self.rng, crown or self.crown)
        if self.occ.take(s, d, trunk[0].half[0] + 0.3):
            self.place(trunk, s, d, TRUNK)
            self.place(crown_parts, s, d, VEGETATION)


class StreetStyle:
    """A street style: ranges and hooks. ``build`` makes a :class:`Scene` from a seeded generator."""

    name = "street"
    speed = (7.0, 12.0)  # ego speed range (m/s)
    straight = 0.5  # share of straight streets
    min_radius = 70.0
    kerb = (0.08, 0.18)  # kerb height range (metres)
    crown = (0.04, 0.12)  # crown drop from centre line to kerb (metres)
    hilly = (0.5, 1.0)  # (share of sloped streets, how steep)
    parked = 0.7
    traffic = 1.0
    pedestrians = 1.0
    vehicles = ((CAR, 0.82), (TRUCK, 0.04), (BUS, 0.03), (OTHER_VEHICLE, 0.05), (MOTORCYCLIST, 0.06))

    # -- hooks ----------------------------------------------------------------------------------
    def section(self, rng: np.random.Generator) -> Section:
        raise NotImplementedError

    def kerbside(self, rng: np.random.Generator, side: int, bins_s: np.ndarray, width: float) -> np.ndarray:
        """``(n,) int32`` class of the kerbside strip per 1 m bin (parking, or raised terrain/sidewalk)."""
        cls = np.full(bins_s.size, PARKING if width > 0 else SIDEWALK, np.int32)
        s = bins_s[0]
        while s < bins_s[-1]:  # bulb-outs between parking runs
            s += rng.uniform(15.0, 60.0)
            length = rng.uniform(4.0, 10.0)
            cls[(bins_s >= s) & (bins_s < s + length)] = SIDEWALK if rng.random() < 0.6 else TERRAIN
            s += length
        return cls

    def lots(self, rng: np.random.Generator, side: int, s_lo: float, s_hi: float) -> list[Lot]:
        """The lots behind the sidewalk of ``side``."""
        lots, s = [], s_lo
        while s < s_hi:
            length = rng.uniform(12.0, 45.0)
            kind = str(rng.choice(["building", "park", "field", "paved"], p=[0.5, 0.2, 0.15, 0.15]))
            lots.append(Lot(side, s, min(s + length, s_hi), kind))
            s += length
        return lots

    def lot_ground(self, rng: np.random.Generator, lot: Lot) -> int:
        return 49 if lot.kind in ("paved", "bigbox") or rng.random() < 0.25 else TERRAIN

    def paint(self, ctx_paint: Painting) -> None:
        """Overlays on the painted cross-section (junctions, driveways, lot markings)."""

    def populate(self, ctx: Ctx) -> None:
        """Traffic, parked things and stuff; sets ``ctx.ego_d``."""
        default_populate(self, ctx)

    def placer(self, ctx: Ctx) -> StylePlacer:
        return StylePlacer(ctx.rng, ctx.road, ctx.street, ctx.occ)

    # -- the build --------------------------------------------------------------------------------
    def make_road(self, rng: np.random.Generator, s_min: float, s_max: float) -> Road:
        road = Road.generate(rng, s_min, s_max, self.min_radius)
        if rng.random() < self.straight:
            return Road(road.s, np.stack([road.s, np.zeros_like(road.s)], axis=1), np.zeros_like(road.s))
        return road

    def build(self, rng: np.random.Generator, duration: float, config: SynthConfig) -> Scene:
        """Draw a street of this style around an ego drive of ``duration`` seconds."""
        ego_speed = float(rng.uniform(*self.speed))
        surge = (
            float(rng.uniform(0.0, 0.8)),
            float(rng.uniform(15.0, 30.0)),
            float(rng.uniform(0, 2 * np.pi)),
        )
        slack = 2 * surge[0] * surge[1] / (2 * np.pi)
        reach = config.view_radius
        s_lo, s_hi = -reach - 20.0, ego_speed * duration + reach + 20.0
        road = self.make_road(rng, s_lo - 400.0, s_hi + 400.0)
        sec = self.section(rng)
        street = self._street(rng, sec, s_lo, s_hi)
        kerb = float(rng.uniform(*self.kerb)) if self.kerb[1] > 0 else 0.0
        crown = float(rng.uniform(*self.crown))
        sloped = rng.random() < self.hilly[0]
        grade = grade_profile(rng, self.hilly[1] if sloped else 0.0)

        xy = np.stack(road.pose_at(np.arange(s_lo, s_hi + 1.0, 2.0))[:2], axis=1)
        canvas = make_canvas(road, xy.min(axis=0) - reach - 5.0, xy.max(axis=0) + reach + 5.0)
        painting = Painting(rng, canvas, street, sec, *paint_section(canvas, street, sec))
        self.paint(painting)
        height = street_height(canvas.hs, canvas.hd, grade, crown, sec.carriageway)
        ground = finish(canvas, painting.cls, painting.raised, height, kerb)
        del canvas, painting

        occ = Occupancy()
        traffic = Traffic(rng, road, street, occ, shapes=dict(STYLE_SHAPES))
        ctx = Ctx(
            rng, config, road, street, sec, ground, occ, traffic, ego_speed, slack, duration, s_lo, s_hi
        )
        self.populate(ctx)
        static = lift(PrimitiveSet.concat([traffic.static(), *ctx.stuff]), ground)
        actors = traffic.actors()
        return Scene(
            road,
            street.layout,
            static,
            actors,
            ctx.ego_d,
            ego_speed,
            traffic.things,
            surge,
            ground,
            None,
            self.name,
        )

    def _street(self, rng: np.random.Generator, sec: Section, s_lo: float, s_hi: float) -> Street:
        n = int(np.ceil(s_hi - s_lo)) + 1
        bins_s = s_lo + np.arange(n) + 0.5
        edges = np.zeros((2, 4, n))
        classes = np.full((2, 2, n), TERRAIN, dtype=np.int32)
        lots: list[Lot] = []
        for side in range(2):
            edges[side] = sec.edges(side)[:, None]
            for lot in self.lots(rng, side, s_lo, s_hi):
                classes[side, 1, (bins_s >= lot.s0) & (bins_s < lot.s1)] = self.lot_ground(rng, lot)
                lots.append(lot)
            classes[side, 0] = self.kerbside(rng, side, bins_s, sec.widths[side][0])
        lay = GroundLayout(s_lo, 1.0, edges, classes, sec.lanes, sec.lane_width)
        parking = []
        for side in range(2):
            if sec.widths[side][0] >= 1.5:
                parking += [
                    (side, s_lo + a, s_lo + b) for a, b in _runs(classes[side, 0] == PARKING) if b - a >= 3
                ]
        return Street(lay, lots, parking)


@dataclass
class Painting:
    """The rasters a style paints on, with the canvas coordinates."""

    rng: np.random.Generator
    canvas: Canvas
    street: Street
    section: Section
    cls: np.ndarray
    raised: np.ndarray

    def put(self, mask: np.ndarray, cls: int, raised: bool) -> None:
        self.cls[mask] = cls
        self.raised[mask] = raised


def paint_section(canvas: Canvas, street: Street, sec: Section) -> tuple[np.ndarray, np.ndarray]:
    """Paint the cross-section over the canvas: ``(ny, nx) uint8`` classes and ``bool`` raised."""
    lay = street.layout
    s, d = canvas.s, canvas.d
    ad = np.abs(d)
    k = np.clip(((s - lay.s0) / lay.ds).astype(np.int64), 0, lay.edges.shape[2] - 1)
    cls = np.empty(s.shape, np.uint8)
    raised = np.ones(s.shape, bool)
    for side, mask in ((0, d >= 0), (1, d < 0)):
        e = lay.edges[side, :, 0]
        beyond = lay.classes[side, 1][k]
        cls[mask] = beyond[mask]
        cls[mask & (ad < e[3])] = SIDEWALK
        cls[mask & (ad < e[2])] = TERRAIN
        strip = mask & (ad < e[1])
        kerb_cls = lay.classes[side, 0][k][strip]
        cls[strip] = kerb_cls
        raised[strip] = (kerb_cls != PARKING) & (kerb_cls != ROAD) & (not sec.flush_kerbside)
        road = mask & (ad < e[0])
        cls[road] = sec.road_class
        raised[road] = False
    if sec.median > 0:
        med = ad < sec.median / 2
        cls[med] = sec.median_class
        raised[med] = True
    if sec.markings:
        hw = 0.1
        dashed = np.mod(s, DASH_PERIOD) < DASH_ON
        inner, lw = sec.median / 2, sec.lane_width
        marks = np.zeros(s.shape, bool)
        if sec.median == 0:
            marks |= (ad < hw) & (dashed | (sec.lanes > 1))
        else:
            marks |= np.abs(ad - inner - 0.3) < hw
        for m in range(1, sec.lanes):
            marks |= (np.abs(ad - inner - m * lw) < hw) & dashed
        marks |= np.abs(ad - inner - sec.lanes * lw + (0.0 if sec.bike > 0 else 0.3)) < hw
        marks &= ad < sec.carriageway
        cls[marks] = LANE_MARKING
    return cls, raised


def lift(p: PrimitiveSet, ground: RasterGround) -> PrimitiveSet:
    """Stand every primitive on the ground: things move up by the ground height under their
    instance's centre (parts stay together), stuff by the height under each primitive; stuff boxes and
    cylinders standing at z = 0 reach below the ground so slopes and kerbs leave no gap under them."""
    if not len(p):
        return p
    center, half = p.center.copy(), p.half.copy()
    thing = p.instance > 0
    if thing.any():
        _, inv = np.unique(p.instance[thing], return_inverse=True)
        count = np.bincount(inv)
        mx = np.bincount(inv, center[thing, 0]) / count
        my = np.bincount(inv, center[thing, 1]) / count
        center[thing, 2] += ground.height_at(mx, my)[inv]
    stuff = ~thing
    center[stuff, 2] += ground.height_at(center[stuff, 0], center[stuff, 1])
    sink = stuff & (p.center[:, 2] - p.half[:, 2] < 0.05) & (p.kind != ELLIPSOID)
    extra = 0.3 + ground.grade * np.hypot(half[:, 0], half[:, 1])
    center[sink, 2] -= extra[sink] / 2
    half[sink, 2] += extra[sink] / 2
    return PrimitiveSet(p.kind, center, p.yaw, half, p.semantic, p.instance, p.reflectivity)


def lanes_of(style: StreetStyle, ctx: Ctx) -> tuple[dict[float, float], float]:
    """Traffic lanes ``{d: signed speed}`` (right-hand traffic) and the ego's lane offset."""
    rng, sec = ctx.rng, ctx.section
    centres = sec.lane_centres()
    ego_lane = int(rng.integers(0, len(centres)))
    ego_d = -centres[ego_lane]
    lo, hi = 0.6 * style.speed[0], 1.3 * style.speed[1]
    roads = {
        -c: ctx.ego_speed if k == ego_lane else float(rng.uniform(lo, hi)) for k, c in enumerate(centres)
    }
    roads.update({c: -float(rng.uniform(lo, hi)) for c in centres})
    return roads, ego_d


def sidewalk_lanes(ctx: Ctx) -> dict[tuple[float, int], tuple[float, float, float]]:
    """Walking lanes ``(sign, k) -> (d, speed, share in pairs)`` on sidewalks at least 1.2 m wide."""
    rng, lay = ctx.rng, ctx.street.layout
    walks = {}
    for side, sign in enumerate(SIDES):
        curb, outer = lay.edge(side, 2, 0.0), lay.edge(side, 3, 0.0) - SIDEWALK_BAND
        if outer - curb < 0.3:
            continue
        pairs = 0.35 if outer - curb >= 2.4 else 0.0
        for k, (frac, direction) in enumerate(((0.3, 1.0), (0.75, -1.0))):
            walks[sign, k] = (
                sign * (curb + frac * (outer - curb)),
                direction * rng.uniform(0.8, 1.6),
                pairs * (k == 0),
            )
    return walks


def default_populate(style: StreetStyle, ctx: Ctx, walks: bool = True) -> None:
    """Lane traffic (vehicles, bicyclists on bike lanes, people on sidewalks), a car ahead of the ego,
    parked vehicles, sidewalk things and the style's stuff."""
    rng, traffic, sec = ctx.rng, ctx.traffic, ctx.section
    roads, ctx.ego_d = lanes_of(style, ctx)
    traffic.reserve(ctx.ego_d, -8.0 - ctx.slack, 8.0 + ctx.slack)
    traffic.drive(CAR, rng.uniform(18.0, 30.0), ctx.ego_d, ctx.ego_speed)
    opposite = min(d for d in roads if d > 0)
    traffic.drive(CAR, rng.uniform(10.0, 40.0), opposite, roads[opposite])
    walk_lanes = sidewalk_lanes(ctx) if walks else {}
    if (1.0, 1) in walk_lanes:
        d, speed, _ = walk_lanes[1.0, 1]
        traffic.drive(PERSON, rng.uniform(5.0, 15.0), d, speed)
    traffic.park_street(style.parked)
    if walks and min(sec.widths[0][2], sec.widths[1][2]) >= 1.0:
        traffic.sidewalk_things(ctx.s_lo, ctx.s_hi)
    classes = [c for c, _ in style.vehicles]
    probs = np.array([p for _, p in style.vehicles])
    probs /= probs.sum()

    def vehicle():
        return classes[rng.choice(len(classes), p=probs)]

    dense = 1.0 / max(ctx.config.traffic * style.traffic, 1e-3)
    for d, speed in roads.items():
        traffic.fill_lane(d, speed, *ctx.window(speed), (15.0 * dense, 90.0 * dense), vehicle)
    if sec.bike > 0:
        for sign in SIDES:
            d, speed = sign * (sec.carriageway - sec.bike / 2), -sign * rng.uniform(3.5, 6.5)
            traffic.fill_lane(d, speed, *ctx.window(speed), (30.0 * dense, 150.0 * dense), lambda: BICYCLIST)
    walk = 1.0 / max(ctx.config.pedestrians * style.pedestrians, 1e-3)
    for d, speed, pairs in walk_lanes.values():
        traffic.fill_lane(d, speed, *ctx.window(speed), (6.0 * walk, 60.0 * walk), lambda: PERSON, pairs)
    ctx.stuff.append(style.placer(ctx).run().build())


def force_take(occ: Occupancy, s: float, d: float, length: float, width: float, yaw: float = 0.0) -> None:
    """Mark a footprint as used whatever lies there (a cross road nothing may be placed on)."""
    from dsnet_core.synth.layout import _corners

    rect = (s, d, length / 2, width / 2, yaw)
    occ.buckets.setdefault(int(s // 10.0), []).append((rect, _corners(rect)))
