"""Styles that are more than one cross-section: a T-junction or crossroads ahead of the ego, and a
parking lot whose aisle the ego drives along (the main road is straight, so Frenet = world)."""

from __future__ import annotations

import numpy as np

from dsnet_core.synth import shapes, templates
from dsnet_core.synth.layout import BUILDING, FENCE, OTHER_OBJECT, POLE, SIDES, Lot
from dsnet_core.synth.primitives import BOX, CYLINDER, Part
from dsnet_core.synth.road import LANE_MARKING, PARKING, ROAD, SIDEWALK, TERRAIN
from dsnet_core.synth.styles.base import Ctx, Painting, Section, StreetStyle, StylePlacer
from dsnet_core.synth.styles.populate import default_populate, force_take
from dsnet_core.synth.traffic import CAR, MOTORCYCLE, OTHER_VEHICLE, PERSON


class Junction(StreetStyle):
    """A straight street with a T-junction or a crossroads 25–55 m ahead: cross-road carriageway and
    sidewalks, stop lines and zebra crossings, cars waiting on the cross road, people at the corners."""

    name = "junction"
    speed = (6.0, 11.0)
    straight = 1.0
    parked = 0.6

    def section(self, rng: np.random.Generator) -> Section:
        widths = tuple(
            (
                2.2 if rng.random() < 0.5 else 0.0,
                rng.uniform(0.8, 2.0) if rng.random() < 0.5 else 0.0,
                rng.uniform(1.5, 3.0),
            )
            for _ in range(2)
        )
        self.s_j = float(rng.uniform(25.0, 55.0))
        self.arms = (0, 1) if rng.random() < 0.5 else (int(rng.integers(0, 2)),)
        self.angle = float(rng.uniform(-0.25, 0.25))
        self.cross_lane = float(rng.uniform(3.0, 3.5))
        self.cross_walk = float(rng.uniform(1.5, 3.0))
        self.reach = self.cross_lane + self.cross_walk + 1.0
        return Section(
            int(rng.integers(1, 3)),
            float(rng.uniform(3.0, 3.5)),
            bike=float(rng.uniform(1.4, 1.8)) if rng.random() < 0.3 else 0.0,
            widths=widths,
        )

    def _halfspan(self) -> float:
        return self.reach / np.cos(self.angle) + 2.0

    def lots(self, rng: np.random.Generator, side: int, s_lo: float, s_hi: float) -> list[Lot]:
        lots = super().lots(rng, side, s_lo, s_hi)
        if side not in self.arms:
            return lots
        a, b = self.s_j - self._halfspan() - 6.0, self.s_j + self._halfspan() + 6.0  # corners are open
        out = []
        for lot in lots:
            for lo, hi in ((lot.s0, min(lot.s1, a)), (max(lot.s0, b), lot.s1)):
                if hi - lo > 6.0:
                    out.append(Lot(lot.side, lo, hi, lot.kind))
        return out

    def kerbside(self, rng: np.random.Generator, side: int, bins_s: np.ndarray, width: float) -> np.ndarray:
        cls = super().kerbside(rng, side, bins_s, width)
        span = self._halfspan() + 5.0
        cls[np.abs(bins_s - self.s_j) < span] = SIDEWALK  # no parking at the junction
        return cls

    def _uv(self, x: np.ndarray, y: np.ndarray, sign: float) -> tuple[np.ndarray, np.ndarray]:
        """Coordinates along the arm on side ``sign`` (u out from the main road's centre line) and
        across it (v)."""
        a = sign * np.pi / 2 + self.angle
        dx, dy = x - self.s_j, y
        return dx * np.cos(a) + dy * np.sin(a), -dx * np.sin(a) + dy * np.cos(a)

    def paint(self, p: Painting) -> None:
        sec = p.section
        x, y = p.canvas.x, p.canvas.y
        ad = np.abs(p.canvas.d)
        half = self.cross_lane
        for side in self.arms:
            sign = SIDES[side]
            e0 = p.street.layout.edges[side, 0, 0]
            u, v = self._uv(x, y, sign)
            out = (sign * y > 0) & (ad >= e0 - 0.01)
            av = np.abs(v)
            p.put(out & (av >= half) & (av < half + self.cross_walk), SIDEWALK, True)
            p.put(out & (av < half), ROAD, False)
            marks = out & (av < 0.1) & (np.mod(u, 9.0) < 3.0) & (u > e0 + 4.0)
            marks |= out & (np.abs(u - e0 - 2.0) < 0.25) & (v > 0) & (v < half)  # stop line
            zebra = out & (u > e0 + 4.0 + self.cross_walk) & (u < e0 + 7.0 + self.cross_walk) & (av < half)
            marks |= zebra & (np.mod(v, 1.0) < 0.5)
            p.put(marks, LANE_MARKING, False)
        s, d = p.canvas.s, p.canvas.d
        zs = self.s_j - self._halfspan() - 4.0
        zebra = (s > zs) & (s < zs + 3.0) & (ad < sec.carriageway - 0.3) & (np.mod(d, 1.0) < 0.5)
        p.put(zebra, LANE_MARKING, False)

    def populate(self, ctx: Ctx) -> None:
        rng, lay = ctx.rng, ctx.street.layout
        for side in self.arms:
            sign = SIDES[side]
            e0 = lay.edge(side, 0, self.s_j)
            a = sign * np.pi / 2 + self.angle
            u = e0 + 3.0
            for _ in range(int(rng.integers(0, 4))):  # cars queuing to enter the main road
                shape = ctx.traffic.shapes[CAR](rng)
                u += shape.length / 2
                v = self.cross_lane / 2
                x = self.s_j + u * np.cos(a) - v * np.sin(a)
                y = u * np.sin(a) + v * np.cos(a)
                ctx.traffic.park(CAR, float(x), float(y), a + np.pi, shape)
                u += shape.length / 2 + rng.uniform(1.5, 4.0)
            for corner in (-1.0, 1.0):  # people waiting at the corners
                if rng.random() < 0.6:
                    u, v = e0 + rng.uniform(2.5, 4.5), corner * (self.cross_lane + self.cross_walk / 2)
                    x = self.s_j + u * np.cos(a) - v * np.sin(a)
                    y = u * np.sin(a) + v * np.cos(a)
                    ctx.traffic.park(PERSON, float(x), float(y), rng.uniform(0, 2 * np.pi))
            length = ctx.config.view_radius
            mid = e0 + length / 2
            force_take(
                ctx.occ,
                self.s_j + mid * np.cos(a),
                mid * np.sin(a),
                length,
                2 * (self.cross_lane + self.cross_walk),
                a,
            )
        default_populate(self, ctx)


class ParkingLot(StreetStyle):
    """The ego drives along a parking-lot aisle: rows of bays with painted lines and parked cars,
    planted islands with trees and tall lights, cross aisles, a big store on one side and trees
    behind a fence on the other; people walking between the cars."""

    name = "parking_lot"
    speed = (2.5, 5.0)
    straight = 1.0
    kerb = (0.1, 0.18)
    crown = (0.0, 0.02)
    hilly = (0.3, 0.4)
    parked = 0.8
    traffic = 0.3
    pedestrians = 0.0

    BAY, AISLE = 5.0, 6.5

    def section(self, rng: np.random.Generator) -> Section:
        lane = float(rng.uniform(3.0, 3.4))
        self.bay_w = float(rng.uniform(2.4, 2.8))
        self.rows: dict[int, list[tuple[float, float, str]]] = {}
        self.edge: dict[int, float] = {}
        self.cross: list[float] = []
        self.store_side = int(rng.integers(0, 2))
        for side in range(2):  # bands outwards from the kerbside bay row: aisle, bays, island, bays...
            d = lane + self.BAY
            rows = [(lane, d, "bays")]
            for _ in range(int(rng.integers(1, 4))):
                rows.append((d, d + self.AISLE, "aisle"))
                d += self.AISLE
                island = rng.uniform(1.5, 2.5) if rng.random() < 0.6 else 0.0
                rows.append((d, d + self.BAY, "bays"))
                d += self.BAY
                if island:
                    rows.append((d, d + island, "island"))
                    d += island
                rows.append((d, d + self.BAY, "bays"))
                d += self.BAY
            self.rows[side], self.edge[side] = rows, d
        return Section(
            1,
            lane,
            widths=((self.BAY, 0.0, 0.0), (self.BAY, 0.0, 0.0)),
            road_class=PARKING,
            markings=False,
            flush_kerbside=True,
        )

    def kerbside(self, rng: np.random.Generator, side: int, bins_s: np.ndarray, width: float) -> np.ndarray:
        if side == 0:
            s = bins_s[0] + rng.uniform(0.0, 40.0)
            while s < bins_s[-1]:
                self.cross.append(float(s))
                s += rng.uniform(50.0, 90.0)
        return np.full(bins_s.size, PARKING, np.int32)

    def lots(self, rng: np.random.Generator, side: int, s_lo: float, s_hi: float) -> list[Lot]:
        return [Lot(side, s_lo, s_hi, "lot")]

    def lot_ground(self, rng: np.random.Generator, lot: Lot) -> int:
        return PARKING

    def _in_cross(self, s: np.ndarray | float) -> np.ndarray:
        """Whether arc lengths ``s`` lie on a 7 m cross aisle (no bays there)."""
        s = np.asarray(s)
        out = np.zeros(s.shape, bool)
        for c in self.cross:
            out |= np.abs(s - c - 3.5) < 3.5
        return out

    def paint(self, p: Painting) -> None:
        s, d = p.canvas.s, p.canvas.d
        ad = np.abs(d)
        cross = self._in_cross(s)
        bay_line = np.mod(s, self.bay_w) < 0.15
        for side, sign in enumerate(SIDES):
            on_side = d * sign > 0
            rows = self.rows[side]
            bounds = np.array([r[1] for r in rows])
            row = np.searchsorted(bounds, ad, side="right")  # index of the band each cell lies in
            inside = on_side & (ad >= rows[0][0]) & (row < len(rows))
            p.raised[inside] = False
            codes = {"bays": 0, "aisle": 1, "island": 2}
            kinds = np.array([codes[r[2]] for r in rows] + [3], np.int8)[row]
            p.put(inside & ~cross & (kinds == 2), TERRAIN, True)
            centre = np.array([(r[0] + r[1]) / 2 for r in rows] + [0.0], np.float32)[row]
            edge_line = np.abs(ad - centre) > self.BAY / 2 - 0.15
            p.put(inside & ~cross & (kinds == 0) & (bay_line | edge_line), LANE_MARKING, False)
            edge = self.edge[side]
            p.put(on_side & (ad >= edge) & (ad < edge + 2.5), SIDEWALK, True)
            p.put(on_side & (ad >= edge + 2.5), 49 if side == self.store_side else TERRAIN, True)

    def populate(self, ctx: Ctx) -> None:
        rng, traffic = ctx.rng, ctx.traffic
        lane = ctx.section.lane_width
        ctx.ego_d = -lane / 2
        traffic.reserve(ctx.ego_d, -8.0 - ctx.slack, 8.0 + ctx.slack)
        traffic.drive(CAR, rng.uniform(15.0, 30.0), ctx.ego_d, ctx.ego_speed)
        speed = -float(rng.uniform(2.0, 5.0))
        traffic.fill_lane(lane / 2, speed, *ctx.window(speed), (30.0, 120.0), lambda: CAR)
        fill = float(rng.uniform(0.5, 0.95))
        placer = StylePlacer(rng, ctx.road, ctx.street, ctx.occ, ctx.wide)
        for side, sign in enumerate(SIDES):
            for d0, d1, kind in self.rows[side]:
                dc = sign * (d0 + d1) / 2
                if kind == "aisle":  # people walking between the rows
                    speed = float(rng.choice([-1.0, 1.0]) * rng.uniform(0.8, 1.4))
                    traffic.fill_lane(dc, speed, *ctx.window(speed), (10.0, 60.0), lambda: PERSON)
                    continue
                if kind == "island":
                    s = ctx.s_lo + rng.uniform(0.0, 8.0)
                    while s < ctx.s_hi:
                        if not self._in_cross(s).any():
                            if rng.random() < 0.2:
                                h = rng.uniform(9.0, 13.0)
                                light = [
                                    Part(CYLINDER, (0.0, 0.0, h / 2), (0.15, 0.15, h / 2), 0.5),
                                    Part(BOX, (0.0, 0.0, h), (0.5, 0.5, 0.1), 0.5),
                                ]
                                if ctx.occ.take(s, dc, 0.4):
                                    placer.place(light, s, dc, POLE)
                            else:
                                placer.tree(s, dc)
                        s += rng.uniform(6.0, 10.0)
                    continue
                for s in np.arange(ctx.s_lo, ctx.s_hi, self.bay_w) + self.bay_w / 2:
                    if self._in_cross(s).any() or rng.random() > fill:
                        continue
                    cls = [CAR, OTHER_VEHICLE, MOTORCYCLE][rng.choice(3, p=[0.86, 0.1, 0.04])]
                    nose = np.pi / 2 + rng.normal(0, 0.04) + rng.choice([0.0, np.pi])
                    traffic.park(cls, float(s), dc + rng.normal(0, 0.1), nose)
                    if rng.random() < 0.04:  # somebody at their car
                        traffic.park(
                            PERSON, float(s) + 1.4, dc + sign * rng.uniform(-1.5, 1.5), rng.uniform(0, 6.3)
                        )
            edge = self.edge[side]
            if side == self.store_side:
                depth, h = rng.uniform(40.0, 80.0), rng.uniform(7.0, 12.0)
                length = ctx.s_hi - ctx.s_lo
                placer.place(
                    [Part(BOX, (0.0, 0.0, h / 2), (length / 2, depth / 2, h / 2), rng.uniform(0.2, 0.6))],
                    (ctx.s_lo + ctx.s_hi) / 2,
                    sign * (edge + 2.5 + depth / 2),
                    BUILDING,
                )
                s = ctx.s_lo + rng.uniform(0.0, 30.0)
                while s < ctx.s_hi:  # trolley shelters, bins
                    box = Part(BOX, (0.0, 0.0, 0.55), (1.0, 0.5, 0.55), rng.uniform(0.3, 0.8))
                    if ctx.occ.take(s, sign * (edge + 1.2), 1.0):
                        placer.place([box], s, sign * (edge + 1.2), OTHER_OBJECT)
                    s += rng.uniform(25.0, 60.0)
            else:
                placer.along(
                    ctx.s_lo, ctx.s_hi, sign * (edge + 3.0), 0.05, rng.uniform(1.0, 2.0), FENCE, 0.35
                )
                s = ctx.s_lo + rng.uniform(0.0, 6.0)
                while s < ctx.s_hi:
                    placer.tree(s, sign * (edge + rng.uniform(5.0, 12.0)), str(rng.choice(shapes.CROWNS)))
                    s += rng.uniform(4.0, 9.0)
            s = ctx.s_lo + rng.uniform(0.0, 30.0)
            while s < ctx.s_hi:
                pole, plate = templates.sign(rng)
                if ctx.occ.take(s, sign * (edge + 0.5), 0.4):
                    placer.place(pole, s, sign * (edge + 0.5), POLE)
                    placer.place(plate, s, sign * (edge + 0.5), 81)
                s += rng.uniform(30.0, 70.0)
        ctx.stuff.append(placer.out.build())
