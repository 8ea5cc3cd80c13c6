"""Residential streets: narrow, lined with parked cars, houses behind hedges, fences and walls."""

from __future__ import annotations

import numpy as np

from dsnet_core.synth import shapes, templates
from dsnet_core.synth.layout import FENCE, SIDES, VEGETATION, Lot
from dsnet_core.synth.primitives import BOX, Part
from dsnet_core.synth.road import PARKING, SIDEWALK, TERRAIN
from dsnet_core.synth.styles.base import Ctx, Painting, Section, StreetStyle, StylePlacer
from dsnet_core.synth.styles.populate import default_populate
from dsnet_core.synth.styles.stuff import boundary, house
from dsnet_core.synth.traffic import CAR, MOTORCYCLIST, OTHER_VEHICLE, TRUCK


class ResidentialPlacer(StylePlacer):
    def __init__(self, ctx: Ctx, driveways: dict[int, list[tuple[float, float]]]) -> None:
        super().__init__(ctx.rng, ctx.road, ctx.street, ctx.occ, ctx.wide)
        self.crown = str(ctx.rng.choice(shapes.CROWNS))
        self.driveways = driveways

    def _lot_house(self, lot: Lot, sign: float, sidewalk_end: float) -> None:
        rng = self.rng
        setback, depth = rng.uniform(6.5, 11.0), rng.uniform(8.0, 13.0)
        s0 = lot.s0 + 4.5  # the driveway runs along the lot's start
        length = lot.s1 - s0 - rng.uniform(1.0, 4.0)
        if length < 5.0:
            return
        house(self, (s0 + s0 + length) / 2, sign * (sidewalk_end + setback + depth / 2), length, depth, sign)
        boundary(self, s0, lot.s1, sign * (sidewalk_end + 0.4))
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
