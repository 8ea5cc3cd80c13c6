"""What every street style shares: the :class:`StreetStyle` build (road, cross-section, painted
raster ground under a graded, crowned surface, traffic, stuff, everything lifted onto the ground).
A style subclasses it, sets its ranges and overrides a few hooks (``section``, ``kerbside``,
``lots``, ``paint``, ``populate``, ``placer``); see :mod:`.section`, :mod:`.painting` and
:mod:`.populate` for the shared pieces."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from dsnet_core.synth import shapes, templates
from dsnet_core.synth.config import SynthConfig
from dsnet_core.synth.ground import (
    RasterGround,
    finish,
    grade_profile,
    make_canvas,
    street_height,
)
from dsnet_core.synth.layout import (
    BUILDING,
    FENCE,
    TRUNK,
    VEGETATION,
    Lot,
    Occupancy,
    Street,
    StuffPlacer,
    _runs,
)
from dsnet_core.synth.primitives import Part, PrimitiveSet
from dsnet_core.synth.road import (
    PARKING,
    SIDEWALK,
    TERRAIN,
    GroundLayout,
    Road,
)
from dsnet_core.synth.scene import Scene
from dsnet_core.synth.styles.painting import Painting, lift, paint_section
from dsnet_core.synth.styles.section import Section
from dsnet_core.synth.styles.wide import Wide, jagged_edges, other_vehicle
from dsnet_core.synth.styles.wide import car as wide_car
from dsnet_core.synth.styles.wide import populate as populate_wide
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
    TRUCK,
    Traffic,
)


def wide_shapes() -> dict:
    """The things of the wide variety: vans are cars, other-vehicle is caravans, trailers, tractors."""
    return {**STYLE_SHAPES, CAR: wide_car, OTHER_VEHICLE: other_vehicle}


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
    wide: Wide | None = None  # the wide variety's draws (None: base)

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
    """The classic stuff placer with varied trees (crown shapes and porosity); with ``wide`` (the
    wide variety) buildings, fences and trunks go through :class:`~.wide.Wide`."""

    crown: str | None = None  # one species for a street's tree rows (None: mixed)

    def __init__(self, rng, road, street, occ, wide: Wide | None = None) -> None:
        super().__init__(rng, road, street, occ)
        self.wide = wide

    def tree(self, s: float, d: float, crown: str | None = None) -> None:
        trunk, crown_parts = shapes.tree(self.rng, crown or self.crown)
        radius = trunk[0].half[0] + 0.3
        if self.occ.take(s, d, radius):
            if self.wide is not None:
                trunk = self.wide.trunk(trunk)
                self.wide.trees.append((s, d, radius))
            self.place(trunk, s, d, TRUNK)
            self.place(crown_parts, s, d, VEGETATION)

    def place(self, parts: list[Part], s: float, d: float, semantic: int, yaw_offset: float = 0.0) -> None:
        if self.wide is not None and semantic == BUILDING:
            parts = self.wide.building(parts)
        elif self.wide is not None and semantic == FENCE and len(parts) == 1:
            parts = [self.wide.fence_part(parts[0])]
        super().place(parts, s, d, semantic, yaw_offset)

    def along(
        self, s0: float, s1: float, d: float, width: float, height: float, semantic: int, refl: float
    ) -> None:
        if self.wide is None or semantic != FENCE:
            return super().along(s0, s1, d, width, height, semantic, refl)
        run = self.wide.fence_run(s0, s1)
        pieces = max(1, int(np.ceil((s1 - s0) / 8.0)))
        step = (s1 - s0) / pieces
        for k in range(pieces):
            sc = s0 + (k + 0.5) * step
            StuffPlacer.place(self, run.piece(sc, step / 2), sc, d, FENCE)


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
        from dsnet_core.synth.styles.populate import default_populate

        default_populate(self, ctx)

    def placer(self, ctx: Ctx) -> StylePlacer:
        return StylePlacer(ctx.rng, ctx.road, ctx.street, ctx.occ, ctx.wide)

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
        wide = Wide.draw(rng) if config.variety == "wide" else None
        if wide is not None:
            kerb = wide.kerb(kerb)
        crown = float(rng.uniform(*self.crown))
        sloped = rng.random() < self.hilly[0]
        grade = grade_profile(rng, self.hilly[1] if sloped else 0.0)

        xy = np.stack(road.pose_at(np.arange(s_lo, s_hi + 1.0, 2.0))[:2], axis=1)
        canvas = make_canvas(road, xy.min(axis=0) - reach - 5.0, xy.max(axis=0) + reach + 5.0)
        painting = Painting(rng, canvas, street, sec, *paint_section(canvas, street, sec))
        self.paint(painting)
        if wide is not None:
            jagged_edges(wide.rng, painting, kerb)
        height = street_height(canvas.hs, canvas.hd, grade, crown, sec.carriageway)
        ground = finish(canvas, painting.cls, painting.raised, height, kerb)
        del canvas, painting

        occ = Occupancy()
        traffic = Traffic(rng, road, street, occ, shapes=wide_shapes() if wide else dict(STYLE_SHAPES))
        ctx = Ctx(
            rng, config, road, street, sec, ground, occ, traffic, ego_speed, slack, duration, s_lo, s_hi,
            wide=wide,
        )  # fmt: skip
        self.populate(ctx)
        surface = None
        if wide is not None:
            populate_wide(wide, ctx, StylePlacer(wide.rng, road, street, occ, wide))
            surface = Surface.draw(wide.rng, xy.min(axis=0) - reach - 5.0, xy.max(axis=0) + reach + 5.0)
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
            surface,
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
