"""The ``wide`` variety of the street styles (``SynthConfig(variety="wide")``, ``dsnet synth --variety
wide``, ``dsnet train dsnet --stream-variety wide``): it widens what the base styles hold fixed
where a class pair is separable by a cue the world lacks (issue #32, ``bench/bench_giveaways.py``,
``docs/synth_giveaways.md``):

- buildings: framed facades (piers, floor bands, balconies, recessed dark glass) and low one-storey
  buildings (garages, sheds, kiosks: 2.2–3.4 m), where base buildings are smooth boxes ≥ 3 m;
- fences (raw class fence, which covers walls): panels, walls, railings, wire mesh and guard rails
  of 0.4–2.6 m, many of them see-through, where base fences are solid slabs ≤ 2 m;
- trunks: bark (stacked cylinders of varied radius) and a lean, where base trunks are perfect
  cylinders; people standing by trees and on grass, where base people keep to sidewalks;
- ground: rough grass over undulating terrain and patchy remission (:mod:`dsnet_core.synth.surface`),
  flush kerbs (sidewalk and grass level with the road) with jagged road edges;
- vehicles: vans count as cars (SemanticKITTI's car covers vans with a continuous body); other-
  vehicle is caravans, trailers and tractors.

Its draws come from a generator spawned from the street's (``Generator.spawn``), so the base draws
keep their order where the wide street only adds detail.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from dsnet_core.synth import shapes
from dsnet_core.synth.layout import SIDES
from dsnet_core.synth.primitives import BOX, CYLINDER, ELLIPSOID, Part
from dsnet_core.synth.road import SIDEWALK, TERRAIN
from dsnet_core.synth.templates import Shape, _wheels
from dsnet_core.synth.traffic import PERSON

if TYPE_CHECKING:
    from dsnet_core.synth.styles.base import Ctx

FENCE_KINDS = ("panel", "wall", "railing", "mesh", "guardrail")


@dataclass
class Wide:
    """A wide street's own draws and what it collects while the street is built.

    Attributes:
        rng: the wide variety's generator.
        textured: share of buildings with a framed facade.
        low: share of buildings that are one low storey.
        by_trees: chance that a person stands by a tree.
        on_grass: people standing on grass per 100 m of street.
        flush: chance of a street without kerbs.
        trees: ``(s, d, radius)`` of every trunk placed (Frenet metres; its footprint radius).
    """

    rng: np.random.Generator
    textured: float
    low: float
    by_trees: float
    on_grass: float
    flush: float
    trees: list[tuple[float, float, float]] = field(default_factory=list)

    @staticmethod
    def draw(rng: np.random.Generator) -> Wide:
        """The wide draws of a street whose own generator is ``rng`` (left where it was)."""
        own = rng.spawn(1)[0]
        return Wide(
            own,
            textured=float(own.uniform(0.5, 0.95)),
            low=float(own.uniform(0.05, 0.3)),
            by_trees=float(own.uniform(0.05, 0.4)),
            on_grass=float(own.uniform(0.0, 2.0)),
            flush=0.25,
        )

    # -- buildings --------------------------------------------------------------------------------
    def building(self, parts: list[Part]) -> list[Part]:
        """``parts`` of a building with its ground-standing walls textured or lowered; parts on top
        (roofs) follow a lowered wall down."""
        rng = self.rng
        out, drop = [], 0.0
        for p in parts:
            if p.kind != BOX or p.center[2] - p.half[2] > 0.1:
                continue
            h = 2 * p.half[2]
            if rng.random() < self.low:
                new = rng.uniform(2.2, 3.4)
                drop, h = max(drop, h - new), min(h, new)
                p = Part(
                    BOX, (p.center[0], p.center[1], h / 2), (p.half[0], p.half[1], h / 2), p.reflectivity
                )
            out += facade(rng, p) if rng.random() < self.textured else [p]
        for p in parts:
            if p.kind != BOX or p.center[2] - p.half[2] > 0.1:
                out.append(
                    Part(p.kind, (p.center[0], p.center[1], p.center[2] - drop), p.half, p.reflectivity)
                )
        return out

    def fence_part(self, part: Part) -> Part:
        """A free-standing fence part (one box) at a new height, 0.4–2.6 m, still on the ground."""
        h = self.rng.uniform(0.4, 2.6)
        return Part(part.kind, (part.center[0], part.center[1], h / 2), (part.half[0], part.half[1], h / 2),
                    part.reflectivity, part.yaw)  # fmt: skip

    def fence_run(self, s0: float, s1: float) -> FenceRun:
        """The kind and make of a fence along ``[s0, s1]``."""
        rng = self.rng
        kind = FENCE_KINDS[int(rng.choice(len(FENCE_KINDS), p=[0.3, 0.25, 0.2, 0.15, 0.1]))]
        height = {"panel": (0.5, 2.5), "wall": (0.4, 2.6), "railing": (0.8, 2.2), "mesh": (1.0, 2.5),
                  "guardrail": (0.6, 0.9)}[kind]  # fmt: skip
        rails = {"railing": int(rng.integers(2, 5)), "mesh": int(rng.integers(6, 13)), "guardrail": 1}
        return FenceRun(
            kind,
            s0,
            float(rng.uniform(*height)),
            float(rng.uniform(0.15, 0.45) if kind == "wall" else rng.uniform(0.03, 0.08)),
            float(rng.uniform(1.5, 3.5)),
            rails.get(kind, 0),
            float(rng.uniform(0.15, 0.7)),
        )

    # -- trees -------------------------------------------------------------------------------------
    def trunk(self, parts: list[Part]) -> list[Part]:
        """A trunk cylinder as stacked pieces of varied radius (bark, stubs) along a slight lean."""
        rng = self.rng
        out = []
        for p in parts:
            h, r = 2 * p.half[2], p.half[0]
            base = p.center[2] - p.half[2]
            n = int(min(8, max(2, np.ceil(h / 0.5))))
            lean = np.tan(np.deg2rad(rng.uniform(0.0, 6.0))) * np.array(
                [np.cos(a := rng.uniform(0, 2 * np.pi)), np.sin(a)]
            )
            wobble = np.cumsum(rng.normal(0.0, 0.02, (n, 2)), axis=0)
            for k in range(n):
                z = base + (k + 0.5) * h / n
                x, y = lean * (z - base) + wobble[k]
                rk = r * rng.uniform(0.8, 1.2)
                out.append(
                    Part(CYLINDER, (float(x), float(y), z), (rk, rk, h / n / 2 + 0.02), p.reflectivity)
                )
        return out

    # -- ground -------------------------------------------------------------------------------------
    def kerb(self, kerb: float) -> float:
        """The street's kerb height: none (flush) with probability :attr:`flush`, else ``kerb``."""
        return 0.0 if self.rng.random() < self.flush else kerb


@dataclass(frozen=True)
class FenceRun:
    """One fence along a street: its kind, first post position ``s0``, height, thickness, post
    spacing, horizontal rails (0: a solid panel or wall) and reflectivity."""

    kind: str
    s0: float
    height: float
    thickness: float
    spacing: float
    rails: int
    reflectivity: float

    def piece(self, sc: float, half_length: float) -> list[Part]:
        """The parts of the piece centred at ``sc`` (in its frame: x along the street)."""
        h, w, refl = self.height, self.thickness, self.reflectivity
        if not self.rails:
            return [Part(BOX, (0.0, 0.0, h / 2), (half_length + 0.02, w / 2, h / 2), refl)]
        parts = []
        first = self.s0 + self.spacing * np.ceil((sc - half_length - self.s0) / self.spacing)
        for s in np.arange(first, sc + half_length, self.spacing):
            parts.append(Part(BOX, (float(s - sc), 0.0, h / 2), (0.05, 0.05, h / 2), refl))
        if self.kind == "guardrail":
            return [*parts, Part(BOX, (0.0, 0.0, h - 0.17), (half_length + 0.02, 0.06, 0.17), refl)]
        bar = 0.02 if self.kind == "mesh" else 0.04
        for k in range(self.rails):
            z = (
                h * (k + 0.5) / self.rails
                if self.kind == "mesh"
                else 0.15 + (h - 0.2) * k / max(1, self.rails - 1)
            )
            parts.append(Part(BOX, (0.0, 0.0, float(z)), (half_length + 0.02, w / 2, bar), refl))
        return parts


def facade(rng: np.random.Generator, wall: Part) -> list[Part]:
    """A wall box as a framed facade: a core set back 0.15–0.45 m behind piers and floor bands
    (dark glass between them), a plinth, sometimes balconies on the long faces."""
    (cx, cy, cz), (hx, hy, hz), refl = wall.center, wall.half, wall.reflectivity
    recess = min(rng.uniform(0.15, 0.45), 0.3 * hy, 0.3 * hx)
    pier = rng.uniform(0.25, 0.7)
    bays = int(np.clip(round(2 * hx / rng.uniform(2.4, 4.5)), 1, 14))
    storey = rng.uniform(2.8, 3.6)
    band = rng.uniform(0.25, 0.9)
    base = cz - hz
    top = cz + hz
    parts = [Part(BOX, (cx, cy, cz), (hx - recess, hy - recess, hz), rng.uniform(0.03, 0.2))]
    for x in np.linspace(-hx + pier / 2, hx - pier / 2, bays + 1):
        parts.append(Part(BOX, (cx + float(x), cy, cz), (pier / 2, hy, hz), refl))
    plinth = rng.uniform(0.4, 1.0) if rng.random() < 0.6 else 0.0
    if plinth:
        parts.append(Part(BOX, (cx, cy, base + plinth / 2), (hx, hy, plinth / 2), refl))
    z = base + storey
    floors = 0
    while z + band / 2 < top and floors < 10:
        parts.append(Part(BOX, (cx, cy, z), (hx, hy, band / 2), refl))
        z += storey
        floors += 1
    parts.append(Part(BOX, (cx, cy, top - band / 4), (hx, hy, band / 4), refl))  # parapet
    if floors >= 2 and rng.random() < 0.3:  # balconies on the long faces
        out = rng.uniform(0.8, 1.4)
        for k in range(1, floors + 1):
            zb = base + k * storey + 0.5
            if zb + 0.5 < top:
                parts.append(Part(BOX, (cx, cy, zb), (hx - pier, hy + out, 0.5), refl))
    return parts


# -- things ---------------------------------------------------------------------------------------
def car(rng: np.random.Generator) -> Shape:
    """A car as SemanticKITTI counts them: hatchbacks, sedans, SUVs and vans."""
    return shapes.vehicle(rng, str(rng.choice(shapes.BODIES, p=[0.3, 0.35, 0.22, 0.13])))


def other_vehicle(rng: np.random.Generator) -> Shape:
    """Other-vehicle: a caravan, a trailer or a tractor."""
    kind = int(rng.choice(3, p=[0.4, 0.35, 0.25]))
    paint = rng.uniform(0.2, 0.9)
    if kind == 0:  # caravan: a tall box with a rounded roof on one axle, a drawbar in front
        length, width, height = rng.uniform(4.5, 7.5), rng.uniform(2.0, 2.4), rng.uniform(2.3, 3.0)
        parts = [
            Part(
                BOX,
                (0.0, 0.0, (0.45 + height - 0.2) / 2),
                (length / 2, width / 2, (height - 0.65) / 2),
                paint,
            ),
            Part(ELLIPSOID, (0.0, 0.0, height - 0.25), (length / 2, width / 2 - 0.05, 0.25), paint),
            Part(BOX, (length / 2 + 0.6, 0.0, 0.45), (0.6, 0.05, 0.04), 0.1),
            *_wheels(0.0, width, 0.33, 0.0)[:2],
        ]
        return Shape(parts, length + 1.2, width, height)
    if kind == 1:  # trailer: a flatbed with side boards, or a closed box, behind a drawbar
        length, width = rng.uniform(2.5, 5.0), rng.uniform(1.5, 2.2)
        top = rng.uniform(0.9, 1.2) if rng.random() < 0.6 else rng.uniform(1.6, 2.4)
        parts = [
            Part(BOX, (0.0, 0.0, (0.5 + top) / 2), (length / 2, width / 2, (top - 0.5) / 2), paint),
            Part(BOX, (length / 2 + 0.7, 0.0, 0.45), (0.7, 0.05, 0.04), 0.1),
            *_wheels(0.0, width, 0.3, 0.0)[:2],
        ]
        return Shape(parts, length + 1.4, width, top)
    length, width = rng.uniform(3.5, 4.5), rng.uniform(1.8, 2.3)  # tractor: hood, cab, big rear wheels
    cab = rng.uniform(2.5, 3.0)
    parts = [
        Part(BOX, (length / 4, 0.0, 1.1), (length / 4, 0.45, 0.4), paint),
        Part(BOX, (-length / 6, 0.0, (1.0 + cab) / 2), (0.7, width / 2 - 0.3, (cab - 1.0) / 2), 0.1),
        Part(ELLIPSOID, (-length / 2 + 0.75, width / 2 - 0.25, 0.75), (0.75, 0.25, 0.75), 0.05),
        Part(ELLIPSOID, (-length / 2 + 0.75, -width / 2 + 0.25, 0.75), (0.75, 0.25, 0.75), 0.05),
        Part(ELLIPSOID, (length / 2 - 0.5, width / 2 - 0.2, 0.45), (0.45, 0.18, 0.45), 0.05),
        Part(ELLIPSOID, (length / 2 - 0.5, -width / 2 + 0.2, 0.45), (0.45, 0.18, 0.45), 0.05),
    ]
    return Shape(parts, length, width, cab)


# -- painting -------------------------------------------------------------------------------------
def jagged_edges(rng: np.random.Generator, painting, kerb: float) -> None:
    """Without kerbs, the carriageway's edge wanders by up to 0.1–0.5 m along the street (broken
    asphalt, grass growing over it): cells across the edge swap road and the class beyond it."""
    sec = painting.section
    if kerb > 0 and not sec.flush_kerbside:
        return
    canvas, lay = painting.canvas, painting.street.layout
    amp = rng.uniform(0.1, 0.5)
    step = rng.uniform(0.5, 3.0)
    knots = np.arange(canvas.s.min() - step, canvas.s.max() + 2 * step, step)
    values = rng.uniform(-amp, amp, (2, knots.size))
    ad = np.abs(canvas.d)
    k = np.clip(((canvas.s - lay.s0) / lay.ds).astype(np.int64), 0, lay.edges.shape[2] - 1)
    for side, mask in ((0, canvas.d >= 0), (1, canvas.d < 0)):
        edge = sec.edges(side)[0]
        wander = np.interp(canvas.s, knots, values[side])
        band = mask & (np.abs(ad - edge) < amp)
        to_road = band & (ad >= edge) & (ad < edge + wander)
        off_road = band & (ad < edge) & (ad >= edge + wander)
        painting.put(to_road, sec.road_class, False)
        verge = TERRAIN if sec.widths[side][1] > 0 else SIDEWALK
        beyond = lay.classes[side, 0][k] if sec.widths[side][0] > 0 else np.full(k.shape, verge)
        painting.cls[off_road] = beyond[off_road]
        painting.raised[off_road] = False


def populate(wide: Wide, ctx: Ctx, placer) -> None:
    """Street trees planted in the paved sidewalk (``placer``: a wide :class:`~.base.StylePlacer`),
    then people standing by trees (a share :attr:`Wide.by_trees` of them) and on grass."""
    rng, traffic = wide.rng, ctx.traffic
    if rng.random() < 0.5:
        for side, sign in enumerate(SIDES):
            e = ctx.street.layout.edges[side, :, 0]
            if e[3] - e[2] < 2.0:
                continue
            s = ctx.s_lo + rng.uniform(0.0, 12.0)
            while s < ctx.s_hi:
                d = sign * (e[2] + rng.uniform(0.5, 1.0))
                if ctx.ground_class(s, d) == SIDEWALK:
                    placer.tree(s, d)
                s += rng.uniform(8.0, 25.0)
        ctx.stuff.append(placer.out.build())
    for s, d, r in wide.trees:
        if rng.random() < wide.by_trees:
            a = rng.uniform(0, 2 * np.pi)
            gap = r + rng.uniform(0.35, 0.9)
            traffic.park(PERSON, s + gap * np.cos(a), d + gap * np.sin(a), rng.uniform(0, 2 * np.pi))
    if wide.on_grass <= 0:
        return
    s = ctx.s_lo + rng.exponential(100.0 / wide.on_grass)
    while s < ctx.s_hi:
        side = int(rng.integers(2))
        e = ctx.street.layout.edges[side, :, 0]
        d = SIDES[side] * rng.uniform(e[0] + 0.5, e[3] + 12.0)
        if ctx.ground_class(s, d) == TERRAIN:
            traffic.park(PERSON, s, d, rng.uniform(0, 2 * np.pi))
        s += rng.exponential(100.0 / wide.on_grass)
