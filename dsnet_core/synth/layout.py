"""The static street: ground layout (lanes, parking strips, sidewalks, lots) and the stuff on it
(buildings, fences, vegetation, trunks, poles, traffic signs)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from dsnet_core.synth import templates
from dsnet_core.synth.primitives import BOX, Part, PrimitiveBuilder
from dsnet_core.synth.road import (
    OTHER_GROUND,
    PARKING,
    SIDEWALK,
    SIDEWALK_END,
    TERRAIN,
    GroundLayout,
    Road,
)

BUILDING, FENCE, VEGETATION, TRUNK, POLE, TRAFFIC_SIGN, OTHER_OBJECT = 50, 51, 70, 71, 80, 81, 99
SIDES = (1.0, -1.0)  # side 0 is the left (d > 0), side 1 the right
SIDEWALK_BAND = 0.9  # outer band of the sidewalk where things stand (bikes, bins, people); no walking


def _corners(rect: tuple[float, float, float, float, float]) -> np.ndarray:
    s, d, hl, hw, yaw = rect
    c, n = np.cos(yaw), np.sin(yaw)
    return np.array([[s + c * hl * a - n * hw * b, d + n * hl * a + c * hw * b] for a, b in _SIGNS])


_SIGNS = ((1, 1), (1, -1), (-1, -1), (-1, 1))


def _disjoint(a: np.ndarray, b: np.ndarray) -> bool:
    """Separating-axis test of two rectangles given as ``(4, 2)`` corners."""
    for poly in (a, b):
        for k in range(2):
            edge = poly[k + 1] - poly[k]
            axis = np.array([-edge[1], edge[0]])
            pa, pb = a @ axis, b @ axis
            if pa.max() <= pb.min() or pb.max() <= pa.min():
                return True
    return False


@dataclass
class Occupancy:
    """Footprints already used on the ground: rectangles in Frenet coordinates (s along, d across),
    bucketed by 10 m of s. Things placed through it never overlap each other."""

    buckets: dict[int, list[tuple[tuple[float, ...], np.ndarray]]] = field(default_factory=dict)

    def take(self, s: float, d: float, r: float) -> bool:
        """Take a round footprint of radius ``r`` (as its bounding square)."""
        return self.take_box(s, d, 2 * r, 2 * r, 0.0, 0.0)

    def take_box(
        self, s: float, d: float, length: float, width: float, yaw: float, margin: float = 0.1
    ) -> bool:
        """Take a ``length`` × ``width`` footprint turned by ``yaw`` from the road direction, grown by
        ``margin``; False (and nothing taken) if it meets a footprint already taken."""
        rect = (s, d, length / 2 + margin, width / 2 + margin, yaw)
        reach = float(np.hypot(rect[2], rect[3]))
        corners = _corners(rect)
        key = int(s // 10.0)
        for k in range(key - 2, key + 3):
            for other, other_corners in self.buckets.get(k, []):
                far = (other[0] - s) ** 2 + (other[1] - d) ** 2 > (reach + np.hypot(other[2], other[3])) ** 2
                if not far and not _disjoint(corners, other_corners):
                    return False
        self.buckets.setdefault(key, []).append((rect, corners))
        return True


@dataclass(frozen=True)
class Lot:
    side: int
    s0: float
    s1: float
    kind: str  # building | park | field | paved


@dataclass(frozen=True)
class Street:
    layout: GroundLayout
    lots: list[Lot]
    parking: list[tuple[int, float, float]]  # (side, s0, s1) parking strips

    def bulb_outs(self, side: int, min_length: float = 4.0) -> list[tuple[float, float]]:
        """Raised (not parking) stretches ``(s0, s1)`` of the kerbside strip of ``side``."""
        lay = self.layout
        if lay.edges[side, 1, 0] - lay.edges[side, 0, 0] < 1.5:
            return []
        runs = _runs(lay.classes[side, 0] != PARKING)
        return [(lay.s0 + a * lay.ds, lay.s0 + b * lay.ds) for a, b in runs if (b - a) * lay.ds >= min_length]

    def set_kerb(self, side: int, s0: float, s1: float, cls: int) -> bool:
        """Make the kerbside strip of ``side`` over ``[s0, s1]`` parking or a raised bay (``cls``);
        False if that side has no kerbside strip."""
        lay = self.layout
        if lay.edge(side, 1, s0) - lay.edge(side, 0, s0) < 1.5:
            return False
        lay.classes[side, 0, lay.bin(s0) : lay.bin(s1) + 1] = cls
        runs = _runs(lay.classes[side, 0] == PARKING)
        self.parking[:] = [p for p in self.parking if p[0] != side]
        self.parking.extend((side, lay.s0 + a * lay.ds, lay.s0 + b * lay.ds) for a, b in runs)
        return True


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """``[start, end)`` index pairs of the True runs of a 1-D mask."""
    padded = np.concatenate([[False], mask, [False]])
    starts = np.flatnonzero(padded[1:] & ~padded[:-1])
    ends = np.flatnonzero(~padded[1:] & padded[:-1])
    return list(zip(starts.tolist(), ends.tolist(), strict=True))


def make_layout(rng: np.random.Generator, s_lo: float, s_hi: float) -> Street:
    """Draw lanes, kerbside strips (parking bays between grass or paved bulb-outs), grass strips,
    sidewalks and lots over ``[s_lo, s_hi]`` (1 m bins). Curb lines are straight along each side."""
    lanes = int(rng.choice([1, 2], p=[0.6, 0.4]))
    lane_w = float(rng.uniform(3.0, 3.6))
    n = int(np.ceil(s_hi - s_lo)) + 1
    edges = np.zeros((2, 4, n))
    classes = np.full((2, 2, n), TERRAIN, dtype=np.int32)
    bins_s = s_lo + np.arange(n) + 0.5
    lots: list[Lot] = []
    parking: list[tuple[int, float, float]] = []
    for side in range(2):
        widths = [
            lanes * lane_w + rng.uniform(1.3, 1.8),  # traffic lanes and a bike lane
            rng.uniform(2.1, 2.5) if rng.random() < 0.85 else 0.0,
            rng.uniform(1.0, 2.5) if rng.random() < 0.4 else 0.0,
            rng.uniform(2.5, 4.0),
        ]
        edges[side] = np.cumsum(widths)[:, None]
        s = s_lo
        while s < s_hi:
            sel = (bins_s >= s) & (bins_s < s + 80.0)
            classes[side, 0, sel] = TERRAIN if rng.random() < 0.6 else SIDEWALK
            if widths[1] > 0 and rng.random() < 0.7:
                length = rng.uniform(15.0, 70.0)
                sel = (bins_s >= s) & (bins_s < s + length)
                classes[side, 0, sel] = PARKING
                parking.append((side, s, min(s + length, s_hi)))
                s += length
            s += rng.uniform(4.0, 25.0)
        s = s_lo
        while s < s_hi:
            length = rng.uniform(12.0, 45.0)
            kind = str(rng.choice(["building", "park", "field", "paved"], p=[0.5, 0.2, 0.15, 0.15]))
            sel = (bins_s >= s) & (bins_s < s + length)
            classes[side, 1, sel] = OTHER_GROUND if kind == "paved" or rng.random() < 0.3 else TERRAIN
            lots.append(Lot(side, s, min(s + length, s_hi), kind))
            s += length
    return Street(GroundLayout(s_lo, 1.0, edges, classes, lanes, lane_w), lots, parking)


class StuffPlacer:
    """Places stuff primitives along the street (buildings, fences, vegetation, poles, signs)."""

    def __init__(self, rng: np.random.Generator, road: Road, street: Street, occ: Occupancy) -> None:
        self.rng, self.road, self.street, self.occ = rng, road, street, occ
        self.out = PrimitiveBuilder()

    def place(self, parts: list[Part], s: float, d: float, semantic: int, yaw_offset: float = 0.0) -> None:
        x, y, h = self.road.pose_at(s, d)
        self.out.add_parts(parts, float(x), float(y), float(h) + yaw_offset, semantic, 0)

    def along(
        self, s0: float, s1: float, d: float, width: float, height: float, semantic: int, refl: float
    ) -> None:
        """A wall-like box run from ``s0`` to ``s1`` at offset ``d``, split into ≤ 8 m pieces to follow
        the curve."""
        pieces = max(1, int(np.ceil((s1 - s0) / 8.0)))
        step = (s1 - s0) / pieces
        for k in range(pieces):
            sc = s0 + (k + 0.5) * step
            self.place(
                [Part(BOX, (0.0, 0.0, height / 2), (step / 2 + 0.02, width / 2, height / 2), refl)],
                sc,
                d,
                semantic,
            )

    def tree(self, s: float, d: float) -> None:
        trunk, crown = templates.tree(self.rng)
        if self.occ.take(s, d, trunk[0].half[0] + 0.3):
            self.place(trunk, s, d, TRUNK)
            self.place(crown, s, d, VEGETATION)

    def run(self) -> PrimitiveBuilder:
        lay = self.street.layout
        for lot in self.street.lots:
            getattr(self, f"_lot_{lot.kind}")(
                lot, SIDES[lot.side], lay.edge(lot.side, SIDEWALK_END, (lot.s0 + lot.s1) / 2)
            )
        for side, sign in enumerate(SIDES):
            self._sidewalk(side, sign)
        return self.out

    def _sidewalk(self, side: int, sign: float) -> None:
        """Street lights and signs at the curb, trees on grass strips and kerbside bays, bins."""
        rng, lay = self.rng, self.street.layout
        e = lay.edges[side, :, 0]  # curb lines are straight along a side
        s_lo, s_hi = lay.s0, lay.s0 + lay.edges.shape[2] * lay.ds
        s = s_lo + rng.uniform(0.0, 30.0)
        while s < s_hi:
            if self.occ.take(s, sign * (e[1] + 0.4), 0.4):
                self.place(templates.streetlight(rng), s, sign * (e[1] + 0.4), POLE, np.pi / 2 * sign)
            s += rng.uniform(22.0, 40.0)
        s = s_lo + rng.uniform(5.0, 40.0)
        while s < s_hi:
            pole, plate = templates.sign(rng)
            if self.occ.take(s, sign * (e[1] + 0.3), 0.4):
                self.place(pole, s, sign * (e[1] + 0.3), POLE)
                self.place(plate, s, sign * (e[1] + 0.3), TRAFFIC_SIGN)
            s += rng.uniform(8.0, 40.0)
        lawn = e[2] - e[1] > 0.8
        s = s_lo + rng.uniform(0.0, 8.0)
        while s < s_hi:
            if lawn:
                self.tree(s, sign * (e[1] + e[2]) / 2)
            elif (lay.classes[side, 0, [lay.bin(s - 2), lay.bin(s + 2)]] == TERRAIN).all():
                self.tree(s, sign * (e[0] + e[1]) / 2)
            s += rng.uniform(7.0, 13.0)
        s = s_lo + rng.uniform(0.0, 30.0)
        while s < s_hi:
            d = sign * (e[3] - 0.5)
            if self.occ.take(s, d, 0.5):
                box = Part(BOX, (0.0, 0.0, 0.55), (0.3, 0.3, 0.55), rng.uniform(0.1, 0.5))
                self.place([box], s, d, OTHER_OBJECT)
            s += rng.uniform(20.0, 80.0)

    def _lot_building(self, lot: Lot, sign: float, sidewalk_end: float) -> None:
        rng = self.rng
        setback = rng.uniform(2.0, 8.0) if rng.random() < 0.75 else 0.0
        depth, height = rng.uniform(8.0, 20.0), rng.uniform(4.0, 25.0)
        gap = rng.uniform(0.5, 6.0)
        length = lot.s1 - lot.s0 - gap
        if length < 5.0:
            return
        sc = (lot.s0 + lot.s1) / 2
        d = sign * (sidewalk_end + setback + depth / 2)
        self.place(
            [Part(BOX, (0.0, 0.0, height / 2), (length / 2, depth / 2, height / 2), rng.uniform(0.15, 0.55))],
            sc,
            d,
            BUILDING,
        )
        if setback > 1.5:  # a front yard: fence or hedge at the sidewalk, bushes on the lawn
            dy = sign * (sidewalk_end + 0.3)
            if rng.random() < 0.4:
                self.along(lot.s0, lot.s1, dy, 0.05, rng.uniform(0.8, 1.8), FENCE, rng.uniform(0.2, 0.5))
            elif rng.random() < 0.8:
                self.along(lot.s0, lot.s1, dy, rng.uniform(0.5, 1.0), rng.uniform(0.8, 1.8), VEGETATION, 0.45)
            for _ in range(int(rng.integers(0, 4))):
                s, d = rng.uniform(lot.s0, lot.s1), sign * (sidewalk_end + rng.uniform(1.0, setback - 0.5))
                if self.occ.take(s, d, 0.8):
                    self.place(templates.bush(rng), s, d, VEGETATION, rng.uniform(0, np.pi))

    def _lot_park(self, lot: Lot, sign: float, sidewalk_end: float) -> None:
        rng = self.rng
        for _ in range(int((lot.s1 - lot.s0) / 5.0)):
            s, d = rng.uniform(lot.s0, lot.s1), sign * (sidewalk_end + rng.uniform(2.0, 25.0))
            if rng.random() < 0.6:
                self.tree(s, d)
            elif self.occ.take(s, d, 1.0):
                self.place(templates.bush(rng), s, d, VEGETATION, rng.uniform(0, np.pi))

    def _lot_field(self, lot: Lot, sign: float, sidewalk_end: float) -> None:
        """Open grass with a fence or hedgerow, scattered trees and a tree line behind."""
        rng = self.rng
        d = sign * (sidewalk_end + rng.uniform(0.5, 3.0))
        if rng.random() < 0.5:
            self.along(lot.s0, lot.s1, d, 0.05, rng.uniform(1.0, 2.0), FENCE, rng.uniform(0.2, 0.5))
        else:
            self.along(lot.s0, lot.s1, d, rng.uniform(0.8, 1.5), rng.uniform(1.0, 2.2), VEGETATION, 0.45)
        for _ in range(int((lot.s1 - lot.s0) / 10.0)):
            self.tree(rng.uniform(lot.s0, lot.s1), sign * (abs(d) + rng.uniform(3.0, 15.0)))
        back = abs(d) + rng.uniform(18.0, 35.0)
        for s in np.arange(lot.s0 + 2.0, lot.s1, rng.uniform(3.0, 5.0)):
            self.tree(float(s), sign * (back + rng.uniform(-1.5, 1.5)))

    def _lot_paved(self, lot: Lot, sign: float, sidewalk_end: float) -> None:
        rng = self.rng
        depth, height = rng.uniform(10.0, 25.0), rng.uniform(5.0, 15.0)
        length = lot.s1 - lot.s0 - 1.0
        d = sign * (sidewalk_end + rng.uniform(15.0, 25.0) + depth / 2)
        self.place(
            [Part(BOX, (0.0, 0.0, height / 2), (length / 2, depth / 2, height / 2), rng.uniform(0.15, 0.55))],
            (lot.s0 + lot.s1) / 2,
            d,
            BUILDING,
        )
