"""Model labels -> Panoptic nuScenes panoptic labels (``general`` or ``challenge`` classes).

A nuScenes panoptic label is ``uint16 = class * 1000 + instance`` with instances 1..999 per class
per scene (0 = no instance, stuff). Ground-truth files (``panoptic/v1.0-*/``) hold the 32 general
classes; results the devkit's evaluators read hold the 16 challenge classes. The model's classes
reach the general classes through the explicit class mapping of the two label maps
(:func:`dsnet_core.label_mapping.class_mapping`, ``semantic-kitti-to-panoptic-nuscenes.yaml``),
and the challenge classes through the nuScenes map's ``learning_map``. Instances are renumbered
per scene: each distinct (written class, source instance id) gets the next number of its class in
order of first appearance, so a track keeps its number through the scene and a class change
starts a new instance (as the nuScenes tracking evaluator sees it).
"""

from __future__ import annotations

import numpy as np

from dsnet_core.errors import DsnetError
from dsnet_core.label_mapping import class_mapping
from dsnet_core.labels import LabelMap, load_label_map

MAX_INSTANCE = 999
CLASSES = ("general", "challenge")


class ExportError(DsnetError):
    """A scene cannot be written in the target format (e.g. more than 999 instances of a class)."""


def general_lut(source: LabelMap, target: LabelMap | None = None) -> np.ndarray:
    """Raw source id -> nuScenes general class, ``(65536,) int64`` (unknown raw ids -> noise).

    Raises:
        ConfigError: no mapping between the two label maps, or a bad one
            (:func:`~dsnet_core.label_mapping.class_mapping`).
    """
    return class_mapping(source, target or load_label_map("panoptic-nuscenes")).raw_lut()


class SceneEncoder:
    """Encodes the frames of one scene in order; instance numbers persist across its frames.

    Args:
        scene: scene name (for error messages).
        source: the model's label map (default: the bundled SemanticKITTI map).
        classes: ``general`` (ground-truth files) or ``challenge`` (results for the devkit).
    """

    def __init__(self, scene: str, source: LabelMap | None = None, classes: str = "general") -> None:
        if classes not in CLASSES:
            raise ValueError(f"classes must be one of {CLASSES}, got {classes!r}")
        self.scene = scene
        self.source = source or load_label_map("semantic-kitti")
        self.target = load_label_map("panoptic-nuscenes")
        self.classes = classes
        general = general_lut(self.source, self.target)
        challenge = self.target.lut(66, fill=0).astype(np.int64)  # general -> challenge
        self.lut = general if classes == "general" else challenge[general]
        thing = self.target.is_thing()
        self._thing = thing[challenge] if classes == "general" else thing  # written class -> thing?
        self._names = self.target.labels if classes == "general" else dict(enumerate(self.target.class_names))
        self._ids: dict[int, int] = {}  # class << 32 | source id -> nuScenes instance
        self._count = np.zeros(66, dtype=np.int64)  # instances given per written class

    def encode(self, labels: np.ndarray) -> np.ndarray:
        """``(N,) uint32`` ``sem | inst << 16`` -> ``(N,) uint16`` ``class * 1000 + instance``.

        Raises:
            ExportError: a general class would need more than 999 instances in this scene.
        """
        labels = np.asarray(labels, dtype=np.uint32)
        cls = self.lut[(labels & 0xFFFF).astype(np.int64)]
        inst = (labels >> 16).astype(np.int64)
        thing = self._thing[cls] & (inst > 0)
        keys = (cls[thing] << 32) | inst[thing]
        uniq, first = np.unique(keys, return_index=True)
        for key in uniq[np.argsort(first, kind="stable")]:  # new ids in order of appearance
            key = int(key)
            if key not in self._ids:
                c = key >> 32
                self._count[c] += 1
                if self._count[c] > MAX_INSTANCE:
                    raise ExportError(
                        f"scene {self.scene}: more than {MAX_INSTANCE} instances of nuScenes class "
                        f"{self._names[c]} ({c}); Panoptic nuScenes cannot encode them"
                    )
                self._ids[key] = int(self._count[c])
        out = cls * 1000
        if uniq.size:
            ids = np.array([self._ids[int(k)] for k in uniq], dtype=np.int64)
            out[thing] += ids[np.searchsorted(uniq, keys)]
        return out.astype(np.uint16)
