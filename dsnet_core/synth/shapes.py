"""Richer object templates for the street styles: vehicle bodies with a profile (hood, cabin with a
rounded roof, boot), people of varied build and posture, trees with clumped crowns of varied shape
and porosity, hedges. Parts are in the object's frame (x forward, y left, z up, metres).

The classic street keeps :mod:`templates` (its output is pinned); styles draw from here.
"""

from __future__ import annotations

import numpy as np

from dsnet_core.synth.primitives import BOX, CYLINDER, ELLIPSOID, Part
from dsnet_core.synth.templates import Shape, _wheels, motorcycle

BODIES = ("hatchback", "sedan", "suv", "van")


def vehicle(rng: np.random.Generator, body: str) -> Shape:
    """A passenger vehicle of ``body`` type (one of :data:`BODIES`): lower body, hood and boot at
    the belt line, a glazed cabin with a rounded roof."""
    length, width, height, cabin_frac, cabin_shift = {
        "hatchback": (rng.uniform(3.6, 4.2), rng.uniform(1.65, 1.8), rng.uniform(1.42, 1.55), 0.62, -0.12),
        "sedan": (rng.uniform(4.4, 5.0), rng.uniform(1.75, 1.9), rng.uniform(1.38, 1.5), 0.48, -0.02),
        "suv": (rng.uniform(4.3, 5.0), rng.uniform(1.8, 2.0), rng.uniform(1.65, 1.9), 0.66, -0.1),
        "van": (rng.uniform(4.8, 5.6), rng.uniform(1.9, 2.05), rng.uniform(1.9, 2.4), 0.8, -0.08),
    }[body]
    paint = rng.uniform(0.05, 0.8)
    glass = rng.uniform(0.04, 0.15)
    clearance = 0.2 if body != "suv" else 0.28
    belt = clearance + 0.5 * (height - clearance) + (0.1 if body == "van" else 0.0)
    cabin_len = length * cabin_frac
    cx = cabin_shift * length
    roof = 0.12 * (height - belt)
    parts = [
        Part(BOX, (0.0, 0.0, (clearance + belt) / 2), (length / 2, width / 2, (belt - clearance) / 2), paint),
        Part(
            BOX,
            (cx, 0.0, (belt + height - roof) / 2),
            (cabin_len / 2, width / 2 - 0.07, (height - roof - belt) / 2),
            glass,
        ),
        Part(ELLIPSOID, (cx, 0.0, height - roof), (cabin_len / 2, width / 2 - 0.09, roof), paint),
    ]
    return Shape(
        parts + _wheels(length, width, 0.3 + 0.04 * (body in ("suv", "van")), 0.75), length, width, height
    )


def city_bus(rng: np.random.Generator) -> Shape:
    """A city bus, sometimes articulated (two bodies and a bellows)."""
    width, height = 2.55, rng.uniform(2.9, 3.3)
    articulated = rng.random() < 0.3
    length = rng.uniform(17.0, 18.5) if articulated else rng.uniform(10.0, 12.5)
    paint = rng.uniform(0.3, 0.8)
    parts = [
        Part(BOX, (0.0, 0.0, 0.75), (length / 2, width / 2, 0.42), paint),
        Part(
            BOX,
            (0.0, 0.0, (1.17 + height) / 2),
            (length / 2 - 0.05, width / 2 - 0.03, (height - 1.17) / 2),
            0.1,
        ),
        Part(BOX, (0.0, 0.0, height + 0.12), (length / 2 - 1.5, width / 2 - 0.5, 0.12), paint),
    ]
    if articulated:
        parts.append(Part(BOX, (0.0, 0.0, height / 2 + 0.2), (0.5, width / 2 + 0.02, height / 2 - 0.3), 0.05))
    return Shape(parts + _wheels(length, width, 0.5, 2.4), length, width, height + 0.24)


def truck_with_trailer(rng: np.random.Generator) -> Shape:
    """A tractor unit and a semi-trailer (one instance, raw class truck)."""
    width = rng.uniform(2.45, 2.55)
    cab_len, cab_h = rng.uniform(2.2, 2.6), rng.uniform(3.0, 3.9)
    trailer_len, trailer_h = rng.uniform(12.0, 13.6), rng.uniform(3.6, 4.0)
    length = cab_len + 0.8 + trailer_len
    front = length / 2
    parts = [
        Part(
            BOX,
            (front - cab_len / 2, 0.0, (0.6 + cab_h) / 2),
            (cab_len / 2, width / 2 - 0.05, (cab_h - 0.6) / 2),
            rng.uniform(0.2, 0.8),
        ),
        Part(BOX, (front - cab_len - 0.4, 0.0, 0.9), (0.6, width / 2 - 0.3, 0.25), 0.05),
        Part(
            BOX,
            (front - cab_len - 0.8 - trailer_len / 2, 0.0, (1.2 + trailer_h) / 2),
            (trailer_len / 2, width / 2, (trailer_h - 1.2) / 2),
            rng.uniform(0.3, 0.9),
        ),
    ]
    wheels = _wheels(cab_len * 2, width, 0.52, 0.5)
    wheels = [
        Part(w.kind, (w.center[0] + front - cab_len, *w.center[1:]), w.half, w.reflectivity) for w in wheels
    ]
    rear = _wheels(3.0, width, 0.5, 0.5)
    rear = [Part(w.kind, (w.center[0] - front + 2.5, *w.center[1:]), w.half, w.reflectivity) for w in rear]
    return Shape(parts + wheels + rear, length, width, trailer_h)


def box_truck(rng: np.random.Generator) -> Shape:
    """A rigid lorry: cab with a rounded top, chassis, cargo box."""
    cargo_len, width = rng.uniform(4.0, 8.0), rng.uniform(2.3, 2.55)
    cab_len, cab_h, cargo_h = rng.uniform(1.8, 2.3), rng.uniform(2.5, 3.1), rng.uniform(3.0, 3.8)
    length = cab_len + 0.2 + cargo_len
    front = length / 2
    parts = [
        Part(
            BOX,
            (front - cab_len / 2, 0.0, (0.5 + cab_h) / 2),
            (cab_len / 2, width / 2 - 0.05, (cab_h - 0.5) / 2),
            rng.uniform(0.1, 0.8),
        ),
        Part(ELLIPSOID, (front - cab_len / 2, 0.0, cab_h), (cab_len / 2, width / 2 - 0.1, 0.2), 0.3),
        Part(
            BOX,
            (front - cab_len - 0.2 - cargo_len / 2, 0.0, (1.0 + cargo_h) / 2),
            (cargo_len / 2, width / 2, (cargo_h - 1.0) / 2),
            rng.uniform(0.2, 0.9),
        ),
        Part(BOX, (0.0, 0.0, 0.75), (length / 2 - 0.3, width / 2 - 0.3, 0.2), 0.05),
    ]
    return Shape(parts + _wheels(length, width, 0.5, 1.2), length, width, cargo_h)


def any_car(rng: np.random.Generator) -> Shape:
    """A passenger car of a random body (hatchback, sedan, SUV; vans are other-vehicle)."""
    return vehicle(rng, str(rng.choice(["hatchback", "sedan", "suv"], p=[0.35, 0.4, 0.25])))


def van(rng: np.random.Generator) -> Shape:
    return vehicle(rng, "van")


def any_truck(rng: np.random.Generator) -> Shape:
    return truck_with_trailer(rng) if rng.random() < 0.4 else box_truck(rng)


POSTURES = ("standing", "walking", "carrying", "phone", "crouching")


def person(rng: np.random.Generator, posture: str | None = None) -> Shape:
    """A person of varied height and build in a posture (one of :data:`POSTURES`): legs (apart when
    walking), torso, arms, head; carrying adds a bag, phone raises a forearm, crouching folds the legs."""
    posture = posture or str(rng.choice(POSTURES, p=[0.35, 0.35, 0.12, 0.1, 0.08]))
    h = rng.uniform(1.5, 2.0) if rng.random() > 0.15 else rng.uniform(0.95, 1.45)
    build = rng.uniform(0.8, 1.3)
    cloth, skin = rng.uniform(0.08, 0.6), rng.uniform(0.15, 0.35)
    head_r = max(0.08, 0.062 * h)
    if posture == "crouching":
        h *= 0.62
    leg_h = 0.47 * h
    shoulder = 0.17 * build * (h / 1.75) ** 0.5
    torso_h = h - 2 * head_r - leg_h
    parts = []
    stride = rng.uniform(0.15, 0.3) * h / 1.75 if posture == "walking" else 0.0
    for side in (1.0, -1.0):
        parts.append(
            Part(
                BOX,
                (side * stride / 2, side * 0.09 * build, leg_h / 2),
                (0.07 * build, 0.07 * build, leg_h / 2),
                cloth,
            )
        )
        arm_x = -side * stride / 3
        parts.append(
            Part(
                BOX,
                (arm_x, side * (shoulder + 0.05), leg_h + 0.55 * torso_h),
                (0.05, 0.05, 0.3 * torso_h + 0.05),
                cloth,
            )
        )
    parts.append(
        Part(ELLIPSOID, (0.0, 0.0, leg_h + torso_h / 2), (0.12 * build, shoulder, torso_h / 2 + 0.05), cloth)
    )
    parts.append(Part(ELLIPSOID, (0.0, 0.0, h - head_r), (head_r, head_r * 0.9, head_r), skin))
    if posture == "carrying":
        parts.append(
            Part(BOX, (0.0, -(shoulder + 0.15), leg_h - 0.05), (0.2, 0.07, 0.17), rng.uniform(0.1, 0.7))
        )
    elif posture == "phone":
        parts.append(Part(BOX, (0.18, 0.1, leg_h + 0.75 * torso_h), (0.12, 0.04, 0.04), skin))
    if rng.random() < 0.2:  # a backpack
        parts.append(
            Part(BOX, (-0.2 * build, 0.0, leg_h + 0.6 * torso_h), (0.1, 0.15, 0.2), rng.uniform(0.1, 0.6))
        )
    return Shape(parts, 0.5, 2 * shoulder + 0.25, h)


def two_wheeler(rng: np.random.Generator) -> Shape:
    """A motorcycle or a scooter (smaller wheels, step-through body)."""
    if rng.random() < 0.6:
        return motorcycle(rng)
    r, wb = 0.22, rng.uniform(1.2, 1.35)
    parts = [Part(ELLIPSOID, (sx * wb / 2, 0.0, r), (r, 0.06, r), 0.06) for sx in (1.0, -1.0)] + [
        Part(BOX, (-0.15, 0.0, 0.5), (wb / 2 - 0.2, 0.18, 0.18), rng.uniform(0.2, 0.8)),
        Part(BOX, (wb / 2 - 0.05, 0.0, 0.75), (0.08, 0.2, 0.3), rng.uniform(0.2, 0.8)),
        Part(BOX, (wb / 2 - 0.05, 0.0, 1.08), (0.04, 0.33, 0.03), 0.1),
    ]
    return Shape(parts, wb + 2 * r, 0.7, 1.1)


# -- vegetation -----------------------------------------------------------------------------------
CROWNS = ("round", "columnar", "conifer", "spreading", "sparse")


def tree(rng: np.random.Generator, crown: str | None = None) -> tuple[list[Part], list[Part]]:
    """(trunk parts, crown parts): a trunk and a crown of one to seven foliage clumps. Dense crowns
    are one or two large clumps; sparse ones scatter small clumps with gaps a ray passes through."""
    crown = crown or str(rng.choice(CROWNS, p=[0.3, 0.15, 0.15, 0.2, 0.2]))
    trunk_h, trunk_r = rng.uniform(1.2, 3.2), rng.uniform(0.08, 0.35)
    refl = rng.uniform(0.3, 0.6)
    trunk = [Part(CYLINDER, (0.0, 0.0, trunk_h / 2), (trunk_r, trunk_r, trunk_h / 2), rng.uniform(0.2, 0.4))]
    if crown == "round":
        r = rng.uniform(1.5, 3.5)
        parts = [
            Part(
                ELLIPSOID,
                (0.0, 0.0, trunk_h + 0.8 * r),
                (r, r * rng.uniform(0.85, 1.0), r * rng.uniform(0.8, 1.1)),
                refl,
            )
        ]
    elif crown == "columnar":
        r = rng.uniform(0.7, 1.3)
        hz = rng.uniform(2.5, 5.0)
        parts = [Part(ELLIPSOID, (0.0, 0.0, trunk_h + 0.9 * hz), (r, r, hz), refl)]
    elif crown == "conifer":  # a cone of shrinking discs down to the ground
        trunk_h = rng.uniform(0.3, 1.0)
        base_r, levels = rng.uniform(1.5, 3.0), int(rng.integers(3, 6))
        tier = rng.uniform(1.2, 2.0)
        parts = [
            Part(
                ELLIPSOID,
                (0.0, 0.0, trunk_h + tier * (k + 0.6)),
                (base_r * (1 - k / (levels + 0.5)),) * 2 + (tier * 0.7,),
                refl,
            )
            for k in range(levels)
        ]
        trunk = [Part(CYLINDER, (0.0, 0.0, trunk_h / 2 + tier), (trunk_r, trunk_r, trunk_h / 2 + tier), 0.3)]
    else:  # spreading or sparse: clumps around a wide crown
        n = int(rng.integers(3, 5)) if crown == "spreading" else int(rng.integers(4, 8))
        spread = rng.uniform(2.0, 4.5)
        size = (0.55 if crown == "spreading" else 0.32) * spread
        parts = []
        for k in range(n):
            ang = 2 * np.pi * k / n + rng.normal(0, 0.3)
            rad = spread * rng.uniform(0.35, 0.75)
            z = trunk_h + size * rng.uniform(0.6, 1.6)
            parts.append(
                Part(
                    ELLIPSOID,
                    (rad * np.cos(ang), rad * np.sin(ang), z),
                    (size, size * rng.uniform(0.7, 1.0), size * 0.8),
                    refl,
                )
            )
        parts.append(Part(ELLIPSOID, (0.0, 0.0, trunk_h + size * 1.8), (size, size, size * 0.8), refl))
    return trunk, parts
