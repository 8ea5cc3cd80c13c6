"""Street styles: residential, arterial, downtown and country streets (one cross-section along a
straight or curved road, each with its own ground classes, stuff and traffic)."""

from __future__ import annotations

import numpy as np

from dsnet_core.synth import shapes, templates
from dsnet_core.synth.layout import BUILDING, FENCE, OTHER_OBJECT, POLE, SIDES, TRAFFIC_SIGN, VEGETATION, Lot
from dsnet_core.synth.primitives import BOX, CYLINDER, Part
from dsnet_core.synth.road import OTHER_GROUND, PARKING, SIDEWALK, TERRAIN
from dsnet_core.synth.styles.base import (
    Ctx,
    Painting,
    Section,
    StreetStyle,
    StylePlacer,
    default_populate,
)
from dsnet_core.synth.traffic import BICYCLE, BICYCLIST, BUS, CAR, MOTORCYCLIST, OTHER_VEHICLE, TRUCK


def _wall(placer: StylePlacer, s0: float, s1: float, d: float) -> None:
    """A hedge, a fence or a garden wall of varied height along ``[s0, s1]`` (or nothing)."""
    rng = placer.rng
    kind = rng.choice(4, p=[0.4, 0.25, 0.15, 0.2])
    if kind == 0:
        placer.along(
            s0, s1, d, rng.uniform(0.5, 1.2), rng.uniform(0.6, 2.4), VEGETATION, rng.uniform(0.3, 0.55)
        )
    elif kind == 1:
        placer.along(s0, s1, d, 0.05, rng.uniform(0.6, 2.0), FENCE, rng.uniform(0.2, 0.5))
    elif kind == 2:
        placer.along(s0, s1, d, rng.uniform(0.2, 0.35), rng.uniform(0.4, 1.8), FENCE, rng.uniform(0.2, 0.45))


def _house(placer: StylePlacer, sc: float, d: float, length: float, depth: float, sign: float) -> None:
    """A house: walls and a ridged roof (two stacked, narrower boxes)."""
    rng = placer.rng
    h = rng.uniform(3.0, 7.0)
    refl = rng.uniform(0.15, 0.55)
    parts = [Part(BOX, (0.0, 0.0, h / 2), (length / 2, depth / 2, h / 2), refl)]
    if rng.random() < 0.7:
        roof = rng.uniform(0.15, 0.55)
        parts += [
            Part(
                BOX, (0.0, 0.0, h + 0.6), (length / 2, depth * (0.5 - roof / 2), 0.6), rng.uniform(0.1, 0.4)
            ),
            Part(BOX, (0.0, 0.0, h + 1.6), (length / 2, depth * (0.5 - roof), 0.4), rng.uniform(0.1, 0.4)),
        ]
    placer.place(parts, sc, d, BUILDING)


# -- residential --------------------------------------------------------------------------------
class ResidentialPlacer(StylePlacer):
    def __init__(self, ctx: Ctx, driveways: dict[int, list[tuple[float, float]]]) -> None:
        super().__init__(ctx.rng, ctx.road, ctx.street, ctx.occ)
        self.crown = str(ctx.rng.choice(shapes.CROWNS))
        self.driveways = driveways

    def _lot_house(self, lot: Lot, sign: float, sidewalk_end: float) -> None:
        rng = self.rng
        setback, depth = rng.uniform(6.5, 11.0), rng.uniform(8.0, 13.0)
        s0 = lot.s0 + 4.5  # the driveway runs along the lot's start
        length = lot.s1 - s0 - rng.uniform(1.0, 4.0)
        if length < 5.0:
            return
        _house(self, (s0 + s0 + length) / 2, sign * (sidewalk_end + setback + depth / 2), length, depth, sign)
        _wall(self, s0, lot.s1, sign * (sidewalk_end + 0.4))
        if rng.random() < 0.5:  # a side fence or hedge between gardens
            h = rng.uniform(0.8, 1.9)
            part = Part(BOX, (0.0, 0.0, h / 2), ((setback + depth) / 2, 0.04, h / 2), rng.uniform(0.2, 0.5))
            self.place([part], lot.s1 - 0.1, sign * (sidewalk_end + (setback + depth) / 2), FENCE, np.pi / 2)
        for _ in range(int(rng.integers(0, 4))):
            s, d = rng.uniform(s0, lot.s1), sign * (sidewalk_end + rng.uniform(1.2, setback - 0.8))
            if self.occ.take(s, d, 0.8):
                self.place(templates.bush(rng), s, d, VEGETATION, rng.uniform(0, np.pi))
        if rng.random() < 0.4:
            self.tree(
                rng.uniform(s0, lot.s1), sign * (sidewalk_end + setback + depth + rng.uniform(2.0, 6.0)), None
            )


class Residential(StreetStyle):
    """Narrow streets lined with parked cars, grass verges with a row of one tree species, houses
    behind hedges, fences and walls, driveways crossing the sidewalk."""

    name = "residential"
    speed = (5.0, 9.0)
    min_radius = 60.0
    parked = 0.85
    traffic = 0.5
    pedestrians = 0.7
    vehicles = ((CAR, 0.9), (OTHER_VEHICLE, 0.05), (MOTORCYCLIST, 0.03), (TRUCK, 0.02))

    def section(self, rng: np.random.Generator) -> Section:
        widths = tuple(
            (
                rng.uniform(2.0, 2.3) if rng.random() < 0.85 else 0.0,
                rng.uniform(0.8, 2.5) if rng.random() < 0.7 else 0.0,
                rng.uniform(1.2, 2.0),
            )
            for _ in range(2)
        )
        self.driveways: dict[int, list[tuple[float, float]]] = {0: [], 1: []}
        return Section(1, float(rng.uniform(2.7, 3.2)), widths=widths, markings=rng.random() < 0.4)

    def lots(self, rng: np.random.Generator, side: int, s_lo: float, s_hi: float) -> list[Lot]:
        lots, s = [], s_lo
        while s < s_hi:
            length = rng.uniform(12.0, 22.0)
            kind = "house" if rng.random() < 0.88 else "park"
            lots.append(Lot(side, s, min(s + length, s_hi), kind))
            if kind == "house":
                self.driveways[side].append((s + 0.5, s + 3.8))
            s += length
        return lots

    def lot_ground(self, rng: np.random.Generator, lot: Lot) -> int:
        return TERRAIN

    def kerbside(self, rng: np.random.Generator, side: int, bins_s: np.ndarray, width: float) -> np.ndarray:
        cls = np.full(bins_s.size, PARKING if width > 0 else SIDEWALK, np.int32)
        for a, b in self.driveways[side]:
            cls[(bins_s >= a - 0.5) & (bins_s < b + 0.5)] = SIDEWALK  # the lowered apron: no parking
        return cls

    def paint(self, p: Painting) -> None:
        s, ad = p.canvas.s, np.abs(p.canvas.d)
        for side, sign in enumerate(SIDES):
            e = p.street.layout.edges[side, :, 0]
            on_side = (p.canvas.d * sign) > 0
            for a, b in self.driveways[side]:
                lane = on_side & (s >= a) & (s < b) & (ad >= e[1]) & (ad < e[3] + 6.0)
                p.put(lane & (ad < e[3]), SIDEWALK, True)
                p.put(lane & (ad >= e[3]), PARKING, True)

    def populate(self, ctx: Ctx) -> None:
        rng = ctx.rng
        for side, sign in enumerate(SIDES):  # cars on driveways, nose to the house or the street
            e3 = ctx.street.layout.edge(side, 3, 0.0)
            for a, b in self.driveways[side]:
                if rng.random() < 0.45:
                    ctx.traffic.park(
                        CAR, (a + b) / 2, sign * (e3 + 3.1), sign * np.pi / 2 + rng.choice([0.0, np.pi])
                    )
        default_populate(self, ctx)

    def placer(self, ctx: Ctx) -> StylePlacer:
        return ResidentialPlacer(ctx, self.driveways)


# -- arterial -----------------------------------------------------------------------------------
class Arterial(StreetStyle):
    """Wide multi-lane roads with a grass median planted with trees and lights, or a paved median
    with a barrier; bike lanes, wide verges, large buildings and car lots set back."""

    name = "arterial"
    speed = (10.0, 16.0)
    straight = 0.6
    min_radius = 150.0
    parked = 0.6
    traffic = 1.6
    pedestrians = 0.5
    vehicles = ((CAR, 0.7), (TRUCK, 0.1), (BUS, 0.07), (OTHER_VEHICLE, 0.07), (MOTORCYCLIST, 0.06))

    def section(self, rng: np.random.Generator) -> Section:
        grass = rng.random() < 0.6
        median = rng.uniform(2.5, 8.0) if grass else rng.uniform(1.0, 2.0)
        widths = tuple(
            (
                rng.uniform(2.2, 2.4) if rng.random() < 0.35 else 0.0,
                rng.uniform(1.5, 4.0),
                rng.uniform(2.0, 3.5),
            )
            for _ in range(2)
        )
        return Section(
            int(rng.integers(2, 4)),
            float(rng.uniform(3.2, 3.7)),
            median=float(median),
            median_class=TERRAIN if grass else SIDEWALK,
            bike=float(rng.uniform(1.5, 2.0)) if rng.random() < 0.4 else 0.0,
            widths=widths,
        )

    def lots(self, rng: np.random.Generator, side: int, s_lo: float, s_hi: float) -> list[Lot]:
        lots, s = [], s_lo
        while s < s_hi:
            length = rng.uniform(25.0, 70.0)
            kind = str(rng.choice(["building", "paved", "park", "field"], p=[0.45, 0.3, 0.15, 0.1]))
            lots.append(Lot(side, s, min(s + length, s_hi), kind))
            s += length
        return lots

    def populate(self, ctx: Ctx) -> None:
        default_populate(self, ctx)
        rng, sec = ctx.rng, ctx.section
        placer = StylePlacer(rng, ctx.road, ctx.street, ctx.occ)
        placer.crown = str(rng.choice(shapes.CROWNS))
        if sec.median_class == TERRAIN:
            s = ctx.s_lo + rng.uniform(0.0, 10.0)
            while s < ctx.s_hi:
                if sec.median >= 3.0:
                    placer.tree(s, 0.0)
                s += rng.uniform(7.0, 14.0)
        else:
            placer.along(ctx.s_lo, ctx.s_hi, 0.0, 0.12, rng.uniform(0.8, 1.1), FENCE, rng.uniform(0.3, 0.6))
        s = ctx.s_lo + rng.uniform(0.0, 20.0)
        while s < ctx.s_hi:
            h = rng.uniform(9.0, 12.0)
            parts = [
                Part(CYLINDER, (0.0, 0.0, h / 2), (0.14, 0.14, h / 2), 0.5),
                Part(BOX, (0.0, 0.0, h - 0.1), (0.08, 1.6, 0.06), 0.4),
            ]
            if ctx.occ.take(s, 0.0, 0.3):
                placer.place(parts, s, 0.0, POLE)
            s += rng.uniform(28.0, 40.0)
        ctx.stuff.append(placer.out.build())


# -- downtown -----------------------------------------------------------------------------------
class DowntownPlacer(StylePlacer):
    def __init__(self, ctx: Ctx, pits: dict[int, list[float]]) -> None:
        super().__init__(ctx.rng, ctx.road, ctx.street, ctx.occ)
        self.crown = str(ctx.rng.choice(["round", "columnar", "sparse"]))
        self.pits = pits

    def _lot_facade(self, lot: Lot, sign: float, sidewalk_end: float) -> None:
        """A building flush with the sidewalk, sometimes with a recessed ground floor."""
        rng = self.rng
        depth, height = rng.uniform(10.0, 25.0), rng.uniform(8.0, 40.0)
        length = lot.s1 - lot.s0 - 0.05
        refl = rng.uniform(0.1, 0.6)
        sc = (lot.s0 + lot.s1) / 2
        if rng.random() < 0.3:  # arcade: the upper floors overhang a recessed ground floor
            self.place(
                [Part(BOX, (0.0, 0.0, 2.0), (length / 2, depth / 2 - 1.0, 2.0), refl)],
                sc,
                sign * (sidewalk_end + depth / 2 + 1.0),
                BUILDING,
            )
            self.place(
                [
                    Part(
                        BOX, (0.0, 0.0, (4.0 + height) / 2), (length / 2, depth / 2, (height - 4.0) / 2), refl
                    )
                ],
                sc,
                sign * (sidewalk_end + depth / 2),
                BUILDING,
            )
        else:
            self.place(
                [Part(BOX, (0.0, 0.0, height / 2), (length / 2, depth / 2, height / 2), refl)],
                sc,
                sign * (sidewalk_end + depth / 2),
                BUILDING,
            )

    def _lot_alley(self, lot: Lot, sign: float, sidewalk_end: float) -> None:
        rng = self.rng
        h = rng.uniform(6.0, 20.0)
        self.place(
            [Part(BOX, (0.0, 0.0, h / 2), ((lot.s1 - lot.s0) / 2, 3.0, h / 2), rng.uniform(0.1, 0.5))],
            (lot.s0 + lot.s1) / 2,
            sign * (sidewalk_end + rng.uniform(20.0, 35.0)),
            BUILDING,
        )
        if rng.random() < 0.5:
            box = Part(BOX, (0.0, 0.0, 0.65), (0.6, 0.5, 0.65), rng.uniform(0.1, 0.5))  # a bin
            self.place([box], (lot.s0 + lot.s1) / 2, sign * (sidewalk_end + 4.0), OTHER_OBJECT)

    def _sidewalk(self, side: int, sign: float) -> None:
        super()._sidewalk(side, sign)
        e = self.street.layout.edges[side, :, 0]
        for s in self.pits[side]:
            self.tree(s, sign * (e[2] + 1.0))


class Downtown(StreetStyle):
    """City centre: buildings flush with wide sidewalks, trees in pits, bulb-outs with bike racks,
    rows of parked bicycles, many pedestrians, buses."""

    name = "downtown"
    speed = (4.0, 9.0)
    straight = 0.7
    min_radius = 100.0
    kerb = (0.1, 0.2)
    parked = 0.8
    traffic = 1.2
    pedestrians = 3.0
    vehicles = ((CAR, 0.75), (BUS, 0.08), (OTHER_VEHICLE, 0.08), (TRUCK, 0.03), (MOTORCYCLIST, 0.06))

    def section(self, rng: np.random.Generator) -> Section:
        widths = tuple((2.2 if rng.random() < 0.8 else 0.0, 0.0, rng.uniform(3.0, 6.0)) for _ in range(2))
        self.pits: dict[int, list[float]] = {0: [], 1: []}
        return Section(
            int(rng.integers(1, 3)),
            float(rng.uniform(3.0, 3.4)),
            bike=float(rng.uniform(1.4, 1.8)) if rng.random() < 0.3 else 0.0,
            widths=widths,
        )

    def lots(self, rng: np.random.Generator, side: int, s_lo: float, s_hi: float) -> list[Lot]:
        lots, s = [], s_lo
        while s < s_hi:
            alley = rng.random() < 0.1
            length = rng.uniform(3.0, 6.0) if alley else rng.uniform(8.0, 30.0)
            lots.append(Lot(side, s, min(s + length, s_hi), "alley" if alley else "facade"))
            s += length
        if rng.random() < 0.6:
            s = s_lo + rng.uniform(0.0, 10.0)
            while s < s_hi:
                self.pits[side].append(float(s))
                s += rng.uniform(8.0, 14.0)
        return lots

    def lot_ground(self, rng: np.random.Generator, lot: Lot) -> int:
        return OTHER_GROUND

    def paint(self, p: Painting) -> None:
        s, ad = p.canvas.s, np.abs(p.canvas.d)
        for side, sign in enumerate(SIDES):
            e2 = p.street.layout.edges[side, 2, 0]
            on_side = (p.canvas.d * sign) > 0
            for sc in self.pits[side]:
                p.put(on_side & (np.abs(s - sc) < 0.7) & (np.abs(ad - e2 - 1.0) < 0.7), TERRAIN, True)

    def populate(self, ctx: Ctx) -> None:
        rng, lay = ctx.rng, ctx.street.layout
        for side, sign in enumerate(SIDES):  # rows of bicycles at the kerb side of the sidewalk
            e2 = lay.edge(side, 2, 0.0)
            s = ctx.s_lo + rng.uniform(0.0, 30.0)
            while s < ctx.s_hi:
                for _ in range(int(rng.integers(3, 11))):
                    ctx.traffic.park(BICYCLE, s, sign * (e2 + 0.6), np.pi / 2 + rng.normal(0, 0.04))
                    s += rng.uniform(0.7, 0.85)
                s += rng.uniform(20.0, 60.0)
        default_populate(self, ctx)

    def placer(self, ctx: Ctx) -> StylePlacer:
        return DowntownPlacer(ctx, self.pits)


# -- country ------------------------------------------------------------------------------------
class CountryPlacer(StylePlacer):
    def __init__(self, ctx: Ctx) -> None:
        super().__init__(ctx.rng, ctx.road, ctx.street, ctx.occ)
        self.crown = str(ctx.rng.choice(shapes.CROWNS))
        self.avenue = ctx.rng.random() < 0.5

    def _sidewalk(self, side: int, sign: float) -> None:
        """Utility poles, reflector posts, signs and (on an avenue) a row of trees on the verge."""
        rng, lay = self.rng, self.street.layout
        e = lay.edges[side, :, 0]
        s_lo, s_hi = lay.s0, lay.s0 + lay.edges.shape[2] * lay.ds
        if side == 1 or rng.random() < 0.3:
            s = s_lo + rng.uniform(0.0, 40.0)
            while s < s_hi:
                h = rng.uniform(7.5, 10.5)
                pole = [
                    Part(CYLINDER, (0.0, 0.0, h / 2), (0.13, 0.13, h / 2), rng.uniform(0.2, 0.4)),
                    Part(BOX, (0.0, 0.0, h - 0.5), (0.06, 0.9, 0.06), 0.3),
                ]
                if self.occ.take(s, sign * (e[2] - 0.5), 0.4):
                    self.place(pole, s, sign * (e[2] - 0.5), POLE)
                s += rng.uniform(35.0, 55.0)
        s = s_lo + rng.uniform(0.0, 30.0)
        while s < s_hi:
            post = [Part(CYLINDER, (0.0, 0.0, 0.5), (0.05, 0.05, 0.5), 0.9)]
            if self.occ.take(s, sign * (e[1] + 0.2), 0.1):
                self.place(post, s, sign * (e[1] + 0.2), POLE)
            s += rng.uniform(25.0, 50.0)
        s = s_lo + rng.uniform(10.0, 80.0)
        while s < s_hi:
            pole, plate = templates.sign(rng)
            if self.occ.take(s, sign * (e[1] + 0.6), 0.4):
                self.place(pole, s, sign * (e[1] + 0.6), POLE)
                self.place(plate, s, sign * (e[1] + 0.6), TRAFFIC_SIGN)
            s += rng.uniform(40.0, 120.0)
        if self.avenue and e[2] - e[1] > 1.5:
            s = s_lo + rng.uniform(0.0, 6.0)
            while s < s_hi:
                self.tree(s, sign * (e[1] + e[2]) / 2)
                s += rng.uniform(7.0, 12.0)

    def _lot_farm(self, lot: Lot, sign: float, sidewalk_end: float) -> None:
        rng = self.rng
        back = sidewalk_end + rng.uniform(15.0, 40.0)
        length = min(lot.s1 - lot.s0 - 4.0, rng.uniform(10.0, 25.0))
        if length > 5.0:
            _house(self, (lot.s0 + lot.s1) / 2, sign * (back + 6.0), length, 10.0, sign)
            h = rng.uniform(5.0, 9.0)
            self.place(
                [Part(BOX, (0.0, 0.0, h / 2), (length / 2, 8.0, h / 2), rng.uniform(0.2, 0.6))],
                (lot.s0 + lot.s1) / 2,
                sign * (back + 30.0),
                BUILDING,
            )
        _wall(self, lot.s0, lot.s1, sign * (sidewalk_end + rng.uniform(0.5, 3.0)))

    def _lot_woods(self, lot: Lot, sign: float, sidewalk_end: float) -> None:
        rng = self.rng
        edge = sidewalk_end + rng.uniform(2.0, 8.0)
        for _ in range(int((lot.s1 - lot.s0) * 1.2)):
            s, d = rng.uniform(lot.s0, lot.s1), sign * (edge + rng.uniform(0.0, 40.0))
            if rng.random() < 0.75:
                self.tree(s, d, str(rng.choice(shapes.CROWNS)))
            elif self.occ.take(s, d, 1.0):
                self.place(templates.bush(rng), s, d, VEGETATION, rng.uniform(0, np.pi))


class Country(StreetStyle):
    """Rural roads: no kerbs, gravel shoulders, wide grass verges, fields behind fences and
    hedgerows, woods, farms, tree avenues, utility poles; hills and strong crowns."""

    name = "country"
    speed = (12.0, 20.0)
    straight = 0.4
    min_radius = 150.0
    kerb = (0.0, 0.0)
    crown = (0.06, 0.15)
    hilly = (0.8, 1.5)
    parked = 0.0
    traffic = 0.6
    pedestrians = 0.0
    vehicles = ((CAR, 0.75), (TRUCK, 0.12), (OTHER_VEHICLE, 0.08), (MOTORCYCLIST, 0.05))

    def section(self, rng: np.random.Generator) -> Section:
        widths = tuple((rng.uniform(0.5, 2.0), rng.uniform(1.5, 6.0), 0.0) for _ in range(2))
        return Section(1, float(rng.uniform(3.0, 3.6)), widths=widths, flush_kerbside=True)

    def kerbside(self, rng: np.random.Generator, side: int, bins_s: np.ndarray, width: float) -> np.ndarray:
        return np.full(bins_s.size, OTHER_GROUND, np.int32)  # gravel

    def lots(self, rng: np.random.Generator, side: int, s_lo: float, s_hi: float) -> list[Lot]:
        lots, s = [], s_lo
        while s < s_hi:
            length = rng.uniform(40.0, 150.0)
            kind = str(rng.choice(["field", "woods", "farm"], p=[0.6, 0.25, 0.15]))
            lots.append(Lot(side, s, min(s + length, s_hi), kind))
            s += length
        return lots

    def lot_ground(self, rng: np.random.Generator, lot: Lot) -> int:
        return TERRAIN

    def populate(self, ctx: Ctx) -> None:
        default_populate(self, ctx, walks=False)
        rng, sec = ctx.rng, ctx.section
        shoulder = sec.widths[1][0]
        if shoulder >= 1.0:  # cyclists on the gravel shoulder
            d, speed = -(sec.carriageway + shoulder / 2), rng.uniform(4.0, 7.0)
            ctx.traffic.fill_lane(d, speed, *ctx.window(speed), (60.0, 250.0), lambda: BICYCLIST)

    def placer(self, ctx: Ctx) -> StylePlacer:
        return CountryPlacer(ctx)
