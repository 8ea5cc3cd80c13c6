"""Painting a style's ground: the cross-section over the canvas, and standing objects on it."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dsnet_core.synth.ground import Canvas, RasterGround
from dsnet_core.synth.layout import Street
from dsnet_core.synth.primitives import ELLIPSOID, PrimitiveSet
from dsnet_core.synth.road import DASH_ON, DASH_PERIOD, LANE_MARKING, PARKING, ROAD, SIDEWALK, TERRAIN
from dsnet_core.synth.styles.section import Section


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
