"""Traffic and things every street style starts from: lanes, sidewalks, the default population."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from dsnet_core.synth.layout import SIDES, SIDEWALK_BAND, Occupancy, _corners
from dsnet_core.synth.traffic import BICYCLIST, CAR, PERSON

if TYPE_CHECKING:
    from dsnet_core.synth.styles.base import Ctx, StreetStyle


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
    rect = (s, d, length / 2, width / 2, yaw)
    occ.buckets.setdefault(int(s // 10.0), []).append((rect, _corners(rect)))
