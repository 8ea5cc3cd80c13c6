"""SemanticKITTI-encoded labels -> Panoptic nuScenes general-class panoptic labels (``.npz``).

A nuScenes panoptic label is ``uint16 = general class * 1000 + instance`` with instances
1..999 per class per scene (0 = no instance, stuff). The class map is a YAML in package data
(``semantic-kitti-to-nuscenes.yaml``, train class name -> general class id). Instances are
renumbered per scene: each distinct (general class, source instance id) gets the next number of
its class in order of first appearance, so a track keeps its number through the scene and a
class change starts a new instance (as the nuScenes tracking evaluator sees it).
"""

from __future__ import annotations

from importlib import resources

import numpy as np
import yaml

from dsnet_core.errors import ConfigError, DsnetError
from dsnet_core.labels import LabelMap, load_label_map

MAX_INSTANCE = 999


class ExportError(DsnetError):
    """A scene cannot be written in the target format (e.g. more than 999 instances of a class)."""


def general_lut(source: LabelMap, target: LabelMap | None = None) -> np.ndarray:
    """Raw SemanticKITTI id -> nuScenes general class, ``(65536,) int64`` (unknown raw ids -> 0).

    Raises:
        ConfigError: the mapping YAML names a class the source map lacks, or a general class id
            the target map lacks, or sends a thing class to a stuff class.
    """
    target = target or load_label_map("panoptic-nuscenes")
    text = resources.files("dsnet_core.data").joinpath("semantic-kitti-to-nuscenes.yaml").read_text()
    mapping = yaml.safe_load(text)["general"]
    names = {n: i for i, n in enumerate(source.class_names)}
    by_train = np.zeros(source.num_classes, dtype=np.int64)
    for name, general in mapping.items():
        if name not in names or int(general) not in target.labels:
            raise ConfigError(f"semantic-kitti-to-nuscenes.yaml: bad entry {name}: {general}")
        train, challenge = names[name], target.learning_map[int(general)]
        if train in source.things and challenge not in target.things:
            raise ConfigError(f"semantic-kitti-to-nuscenes.yaml: thing {name} mapped to a stuff class")
        by_train[train] = int(general)
    return by_train[source.lut(1 << 16, fill=0)]


class SceneEncoder:
    """Encodes the frames of one scene in order; instance numbers persist across its frames.

    Args:
        scene: scene name (for error messages).
        source: the SemanticKITTI label map (default: bundled).
    """

    def __init__(self, scene: str, source: LabelMap | None = None) -> None:
        self.scene = scene
        self.source = source or load_label_map("semantic-kitti")
        self.target = load_label_map("panoptic-nuscenes")
        self.lut = general_lut(self.source, self.target)
        self._thing = self.target.is_thing()[self.target.lut(66, fill=0)]  # general class -> thing?
        self._ids: dict[int, int] = {}  # general << 32 | source id -> nuScenes instance
        self._count = np.zeros(66, dtype=np.int64)  # instances given per general class

    def encode(self, labels: np.ndarray) -> np.ndarray:
        """``(N,) uint32`` ``sem | inst << 16`` -> ``(N,) uint16`` ``general * 1000 + instance``.

        Raises:
            ExportError: a general class would need more than 999 instances in this scene.
        """
        labels = np.asarray(labels, dtype=np.uint32)
        general = self.lut[(labels & 0xFFFF).astype(np.int64)]
        inst = (labels >> 16).astype(np.int64)
        thing = self._thing[general] & (inst > 0)
        keys = (general[thing] << 32) | inst[thing]
        uniq, first = np.unique(keys, return_index=True)
        for key in uniq[np.argsort(first, kind="stable")]:  # new ids in order of appearance
            key = int(key)
            if key not in self._ids:
                cls = key >> 32
                self._count[cls] += 1
                if self._count[cls] > MAX_INSTANCE:
                    raise ExportError(
                        f"scene {self.scene}: more than {MAX_INSTANCE} instances of nuScenes class "
                        f"{self.target.labels[cls]} ({cls}); Panoptic nuScenes cannot encode them"
                    )
                self._ids[key] = int(self._count[cls])
        out = general * 1000
        if uniq.size:
            ids = np.array([self._ids[int(k)] for k in uniq], dtype=np.int64)
            out[thing] += ids[np.searchsorted(uniq, keys)]
        return out.astype(np.uint16)
