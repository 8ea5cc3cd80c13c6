"""What refinement needs to know of a label map: which train ids are things, stuff, ignored,
ground, and which thing classes a track may change between (its association group)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dsnet_core.labels import LabelMap


@dataclass(frozen=True)
class ClassSets:
    """Per train id ``(C,)`` masks.

    Attributes:
        thing: countable classes (their points carry instance ids).
        stuff: stuff classes (static by nature: they vote and take the static vote).
        ignore: classes never voted for nor assigned (the label map's ``ignore``).
        ground: stuff classes of the ground surface (empty when the map declares none).
        group: ``(C,) int64`` association group of each class (the map's ``track_groups``).
    """

    thing: np.ndarray
    stuff: np.ndarray
    ignore: np.ndarray
    ground: np.ndarray
    group: np.ndarray

    @classmethod
    def from_label_map(cls, label_map: LabelMap) -> ClassSets:
        n = label_map.num_classes
        ignore = np.zeros(n, bool)
        ignore[list(label_map.ignore)] = True
        thing = label_map.is_thing() & ~ignore
        stuff = np.zeros(n, bool)
        stuff[list(label_map.stuff)] = True
        stuff &= ~ignore & ~thing
        ground = np.zeros(n, bool)
        ground[list(label_map.ground)] = True
        return cls(thing, stuff, ignore, ground & stuff, label_map.track_group_of())

    @property
    def num_classes(self) -> int:
        return int(self.thing.size)
