"""Analytic primitives the scene is built from: oriented boxes, vertical cylinders, ellipsoids.

A :class:`PrimitiveSet` is a struct of arrays in world coordinates (metres, z up, ground at z = 0).
Every primitive rotates about the vertical axis only (``yaw``, radians).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

BOX, CYLINDER, ELLIPSOID = 0, 1, 2


@dataclass(frozen=True)
class PrimitiveSet:
    """Primitives as parallel arrays.

    Attributes:
        kind: ``(P,) int32``: BOX, CYLINDER or ELLIPSOID.
        center: ``(P, 3) float64`` centre (metres).
        yaw: ``(P,) float64`` rotation about z (radians).
        half: ``(P, 3) float64`` half extents (box), (radius, radius, half height) (cylinder) or
            semi-axes (ellipsoid), metres.
        semantic: ``(P,) int32`` raw SemanticKITTI id.
        instance: ``(P,) int32`` instance id (0 for stuff).
        reflectivity: ``(P,) float64`` material reflectivity in [0, 1].
    """

    kind: np.ndarray
    center: np.ndarray
    yaw: np.ndarray
    half: np.ndarray
    semantic: np.ndarray
    instance: np.ndarray
    reflectivity: np.ndarray

    def __len__(self) -> int:
        return int(self.kind.shape[0])

    @staticmethod
    def empty() -> PrimitiveSet:
        return PrimitiveSet(
            np.zeros(0, np.int32),
            np.zeros((0, 3)),
            np.zeros(0),
            np.zeros((0, 3)),
            np.zeros(0, np.int32),
            np.zeros(0, np.int32),
            np.zeros(0),
        )

    @staticmethod
    def concat(sets: list[PrimitiveSet]) -> PrimitiveSet:
        sets = [s for s in sets if len(s)]
        if not sets:
            return PrimitiveSet.empty()
        return PrimitiveSet(
            *(np.concatenate([getattr(s, f) for s in sets]) for f in PrimitiveSet.__dataclass_fields__)
        )

    def select(self, mask: np.ndarray) -> PrimitiveSet:
        return PrimitiveSet(*(getattr(self, f)[mask] for f in PrimitiveSet.__dataclass_fields__))


@dataclass(frozen=True)
class Part:
    """One primitive of an object template, in the object's frame (x forward, y left, z up, origin on
    the ground below the object's centre)."""

    kind: int
    center: tuple[float, float, float]
    half: tuple[float, float, float]
    reflectivity: float
    yaw: float = 0.0


class PrimitiveBuilder:
    """Collects primitives, then :meth:`build` returns a :class:`PrimitiveSet`."""

    def __init__(self) -> None:
        self._rows: list[tuple] = []

    def add(
        self,
        kind: int,
        center: tuple[float, float, float],
        yaw: float,
        half: tuple[float, float, float],
        semantic: int,
        instance: int,
        reflectivity: float,
    ) -> None:
        self._rows.append((kind, center, yaw, half, semantic, instance, reflectivity))

    def add_parts(
        self, parts: list[Part], x: float, y: float, yaw: float, semantic: int, instance: int, z: float = 0.0
    ) -> None:
        """Place template ``parts`` at world position ``(x, y, z)`` with heading ``yaw``."""
        c, s = np.cos(yaw), np.sin(yaw)
        for p in parts:
            px, py, pz = p.center
            self.add(
                p.kind,
                (x + c * px - s * py, y + s * px + c * py, z + pz),
                yaw + p.yaw,
                p.half,
                semantic,
                instance,
                p.reflectivity,
            )

    def __len__(self) -> int:
        return len(self._rows)

    def build(self) -> PrimitiveSet:
        if not self._rows:
            return PrimitiveSet.empty()
        kind, center, yaw, half, sem, inst, refl = zip(*self._rows, strict=True)
        return PrimitiveSet(
            np.asarray(kind, np.int32),
            np.asarray(center, np.float64).reshape(-1, 3),
            np.asarray(yaw, np.float64),
            np.asarray(half, np.float64).reshape(-1, 3),
            np.asarray(sem, np.int32),
            np.asarray(inst, np.int32),
            np.asarray(refl, np.float64),
        )
