"""Country roads: no kerbs, gravel shoulders, verges, fields, woods, farms and tree avenues."""

from __future__ import annotations

import numpy as np

from dsnet_core.synth import shapes, templates
from dsnet_core.synth.layout import BUILDING, POLE, TRAFFIC_SIGN, VEGETATION, Lot
from dsnet_core.synth.primitives import BOX, CYLINDER, Part
from dsnet_core.synth.road import OTHER_GROUND, TERRAIN
from dsnet_core.synth.styles.base import Ctx, Section, StreetStyle, StylePlacer
from dsnet_core.synth.styles.populate import default_populate
from dsnet_core.synth.styles.stuff import boundary, house
from dsnet_core.synth.traffic import BICYCLIST, CAR, MOTORCYCLIST, OTHER_VEHICLE, TRUCK


# -- country ------------------------------------------------------------------------------------
class CountryPlacer(StylePlacer):
    def __init__(self, ctx: Ctx) -> None:
        super().__init__(ctx.rng, ctx.road, ctx.street, ctx.occ, ctx.wide)
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
            house(self, (lot.s0 + lot.s1) / 2, sign * (back + 6.0), length, 10.0, sign)
            h = rng.uniform(5.0, 9.0)
            self.place(
                [Part(BOX, (0.0, 0.0, h / 2), (length / 2, 8.0, h / 2), rng.uniform(0.2, 0.6))],
                (lot.s0 + lot.s1) / 2,
                sign * (back + 30.0),
                BUILDING,
            )
        boundary(self, lot.s0, lot.s1, sign * (sidewalk_end + rng.uniform(0.5, 3.0)))

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
