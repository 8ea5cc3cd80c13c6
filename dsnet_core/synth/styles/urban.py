"""Urban streets: wide arterials with medians, and downtown streets between flush facades."""

from __future__ import annotations

import numpy as np

from dsnet_core.synth import shapes
from dsnet_core.synth.layout import BUILDING, FENCE, OTHER_OBJECT, POLE, SIDES, Lot
from dsnet_core.synth.primitives import BOX, CYLINDER, Part
from dsnet_core.synth.road import OTHER_GROUND, SIDEWALK, TERRAIN
from dsnet_core.synth.styles.base import Ctx, Painting, Section, StreetStyle, StylePlacer
from dsnet_core.synth.styles.populate import default_populate
from dsnet_core.synth.traffic import BICYCLE, BUS, CAR, MOTORCYCLIST, OTHER_VEHICLE, TRUCK


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
        placer = StylePlacer(rng, ctx.road, ctx.street, ctx.occ, ctx.wide)
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
        super().__init__(ctx.rng, ctx.road, ctx.street, ctx.occ, ctx.wide)
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
