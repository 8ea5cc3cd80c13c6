"""Object shapes as lists of :class:`Part` in the object's frame (x forward, y left, z up, metres).

Each builder draws its own size from ``rng`` so instances vary (small hatchbacks to vans, children
to tall adults, short vans to articulated trucks). ``length``/``width`` are returned for spacing.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dsnet_core.synth.primitives import BOX, CYLINDER, ELLIPSOID, Part


@dataclass(frozen=True)
class Shape:
    parts: list[Part]
    length: float
    width: float
    height: float


def _wheels(length: float, width: float, radius: float, axle_inset: float, refl: float = 0.05) -> list[Part]:
    parts = []
    for sx in (1.0, -1.0):
        for sy in (1.0, -1.0):
            c = (sx * (length / 2 - axle_inset), sy * (width / 2 - 0.12), radius)
            parts.append(Part(BOX, c, (radius, 0.11, radius), refl))
    return parts


def car(rng: np.random.Generator) -> Shape:
    """Passenger car: hatchback to SUV."""
    length, width = rng.uniform(3.6, 4.9), rng.uniform(1.65, 1.92)
    height = rng.uniform(1.4, 1.75) + (0.2 if length > 4.6 and rng.random() < 0.4 else 0.0)
    paint = rng.uniform(0.05, 0.75)
    belt = 0.3 + 0.45 * (height - 0.3)
    cabin_len = length * rng.uniform(0.45, 0.6)
    parts = [
        Part(BOX, (0.0, 0.0, (0.3 + belt) / 2), (length / 2, width / 2, (belt - 0.3) / 2), paint),
        Part(
            BOX,
            (-0.08 * length, 0.0, (belt + height) / 2),
            (cabin_len / 2, width / 2 - 0.08, (height - belt) / 2),
            rng.uniform(0.05, 0.2),
        ),
    ]
    return Shape(parts + _wheels(length, width, 0.31, 0.8), length, width, height)


def truck(rng: np.random.Generator) -> Shape:
    """Lorry: cab plus cargo box."""
    cargo_len, width = rng.uniform(4.0, 9.5), rng.uniform(2.35, 2.55)
    cab_len, cab_h, cargo_h = 2.2, rng.uniform(2.7, 3.2), rng.uniform(3.0, 3.9)
    length = cab_len + 0.3 + cargo_len
    front = length / 2
    paint = rng.uniform(0.1, 0.8)
    parts = [
        Part(
            BOX,
            (front - cab_len / 2, 0.0, (0.5 + cab_h) / 2),
            (cab_len / 2, width / 2 - 0.05, (cab_h - 0.5) / 2),
            paint,
        ),
        Part(
            BOX,
            (front - cab_len - 0.3 - cargo_len / 2, 0.0, (1.0 + cargo_h) / 2),
            (cargo_len / 2, width / 2, (cargo_h - 1.0) / 2),
            rng.uniform(0.2, 0.8),
        ),
        Part(BOX, (0.0, 0.0, 0.75), (length / 2 - 0.3, width / 2 - 0.3, 0.2), 0.05),
    ]
    return Shape(parts + _wheels(length, width, 0.5, 1.3), length, width, cargo_h)


def bus(rng: np.random.Generator) -> Shape:
    """City bus (raw class bus, train class other-vehicle)."""
    length, width, height = rng.uniform(10.0, 12.5), 2.55, rng.uniform(2.9, 3.2)
    parts = [
        Part(
            BOX,
            (0.0, 0.0, (0.35 + 1.1) / 2),
            (length / 2, width / 2, (1.1 - 0.35) / 2),
            rng.uniform(0.3, 0.8),
        ),
        Part(
            BOX,
            (0.0, 0.0, (1.1 + height) / 2),
            (length / 2 - 0.05, width / 2 - 0.02, (height - 1.1) / 2),
            0.12,
        ),
    ]
    return Shape(parts + _wheels(length, width, 0.5, 2.4), length, width, height)


def van_or_trailer(rng: np.random.Generator) -> Shape:
    """Other vehicle: camper, tractor-trailer, construction vehicle (one box on wheels)."""
    length, width, height = rng.uniform(5.0, 7.5), rng.uniform(2.1, 2.5), rng.uniform(2.4, 3.2)
    parts = [
        Part(
            BOX,
            (0.0, 0.0, (0.55 + height) / 2),
            (length / 2, width / 2, (height - 0.55) / 2),
            rng.uniform(0.2, 0.8),
        )
    ]
    return Shape(parts + _wheels(length, width, 0.4, 1.0), length, width, height)


def person(rng: np.random.Generator, height: float | None = None) -> Shape:
    """Pedestrian: legs, torso, head (children to tall adults)."""
    h = (
        height
        if height is not None
        else (rng.uniform(1.55, 1.95) if rng.random() > 0.1 else rng.uniform(1.0, 1.4))
    )
    cloth = rng.uniform(0.08, 0.6)
    leg_h = 0.47 * h
    head_r = max(0.085, 0.065 * h)
    torso_c = (leg_h + h - 2 * head_r) / 2
    parts = [
        Part(BOX, (0.0, 0.0, leg_h / 2), (0.11, 0.17, leg_h / 2), cloth),
        Part(ELLIPSOID, (0.0, 0.0, torso_c), (0.13, 0.14 * h, (h - 2 * head_r - leg_h) / 2 + 0.06), cloth),
        Part(ELLIPSOID, (0.0, 0.0, h - head_r), (head_r, head_r * 0.9, head_r), 0.15),
    ]
    return Shape(parts, 0.4, 0.55, h)


def _two_wheeler(rng: np.random.Generator, motor: bool) -> tuple[list[Part], float]:
    if motor:
        r, wb, tyre = 0.32, rng.uniform(1.35, 1.6), 0.07
        body = [
            Part(BOX, (0.0, 0.0, 0.62), (wb / 2 - 0.1, 0.2, 0.22), rng.uniform(0.2, 0.8)),
            Part(BOX, (wb / 2 - 0.1, 0.0, 1.0), (0.05, 0.38, 0.04), 0.1),
        ]
    else:
        r, wb, tyre = 0.34, rng.uniform(1.0, 1.12), 0.025
        body = [
            Part(BOX, (0.0, 0.0, 0.62), (wb / 2 - 0.15, 0.025, 0.14), rng.uniform(0.1, 0.7)),
            Part(BOX, (wb / 2 - 0.05, 0.0, 1.0), (0.03, 0.3, 0.02), 0.1),
            Part(BOX, (-0.2, 0.0, 0.88), (0.13, 0.07, 0.03), 0.1),
        ]
    wheels = [Part(ELLIPSOID, (sx * wb / 2, 0.0, r), (r, tyre, r), 0.06) for sx in (1.0, -1.0)]
    return wheels + body, wb + 2 * r


def bicycle(rng: np.random.Generator) -> Shape:
    parts, length = _two_wheeler(rng, motor=False)
    return Shape(parts, length, 0.62, 1.05)


def motorcycle(rng: np.random.Generator) -> Shape:
    parts, length = _two_wheeler(rng, motor=True)
    return Shape(parts, length, 0.8, 1.1)


def _rider(rng: np.random.Generator, motor: bool) -> list[Part]:
    cloth = rng.uniform(0.08, 0.6)
    seat = 0.85 if motor else 0.95
    head_r = 0.15 if motor else 0.11
    return [
        Part(BOX, (0.0, 0.0, seat - 0.2), (0.15, 0.17, 0.25), cloth),
        Part(ELLIPSOID, (0.05, 0.0, seat + 0.32), (0.2, 0.2, 0.32), cloth, 0.0),
        Part(ELLIPSOID, (0.18, 0.0, seat + 0.75), (head_r, head_r * 0.9, head_r), 0.3 if motor else 0.15),
    ]


def bicyclist(rng: np.random.Generator) -> Shape:
    """Bicycle with its rider (one instance, as the SemanticKITTI bicyclist class is annotated here)."""
    parts, length = _two_wheeler(rng, motor=False)
    return Shape(parts + _rider(rng, motor=False), length, 0.6, 1.9)


def motorcyclist(rng: np.random.Generator) -> Shape:
    parts, length = _two_wheeler(rng, motor=True)
    return Shape(parts + _rider(rng, motor=True), length, 0.8, 1.85)


# -- stuff --------------------------------------------------------------------------------------
def tree(rng: np.random.Generator) -> tuple[list[Part], list[Part]]:
    """(trunk parts, crown parts) of a tree."""
    trunk_h, trunk_r = rng.uniform(1.4, 3.0), rng.uniform(0.1, 0.3)
    crown_r, crown_z = rng.uniform(1.5, 4.0), rng.uniform(1.5, 4.5)
    trunk = [Part(CYLINDER, (0.0, 0.0, trunk_h / 2), (trunk_r, trunk_r, trunk_h / 2), rng.uniform(0.2, 0.4))]
    crown = [
        Part(
            ELLIPSOID,
            (0.0, 0.0, trunk_h + 0.6 * crown_z),
            (crown_r, crown_r * rng.uniform(0.8, 1.0), crown_z),
            rng.uniform(0.3, 0.6),
        )
    ]
    return trunk, crown


def bush(rng: np.random.Generator) -> list[Part]:
    a, c = rng.uniform(0.5, 1.6), rng.uniform(0.4, 1.1)
    return [Part(ELLIPSOID, (0.0, 0.0, 0.8 * c), (a, a * rng.uniform(0.6, 1.0), c), rng.uniform(0.3, 0.6))]


def streetlight(rng: np.random.Generator) -> list[Part]:
    h, r = rng.uniform(5.0, 9.0), rng.uniform(0.07, 0.14)
    return [
        Part(CYLINDER, (0.0, 0.0, h / 2), (r, r, h / 2), rng.uniform(0.3, 0.6)),
        Part(BOX, (0.0, 0.7, h - 0.05), (0.06, 0.7, 0.05), 0.4),
    ]


def sign(rng: np.random.Generator) -> tuple[list[Part], list[Part]]:
    """(pole parts, plate parts) of a traffic sign; the plate faces along ±x (oncoming traffic when
    placed with the road heading)."""
    bottom = rng.uniform(1.9, 2.3)  # lower edge of the lowest plate above the sidewalk
    plates, z = [], bottom
    for _ in range(1 if rng.random() < 0.6 else 2):
        w, h = (
            (rng.uniform(0.3, 0.42),) * 2
            if rng.random() < 0.7
            else (rng.uniform(0.4, 0.7), rng.uniform(0.2, 0.3))
        )
        plates.insert(0, Part(BOX, (0.0, 0.0, z + h), (0.02, w, h), rng.uniform(0.85, 1.0)))
        z += 2 * h + 0.05
    pole = [Part(CYLINDER, (0.0, 0.0, z / 2), (0.035, 0.035, z / 2), 0.4)]
    return pole, plates
