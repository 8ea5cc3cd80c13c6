"""Explicit class mappings between two label maps (the model's classes -> a log's ground truth).

A model predicts in its card's label map; a log's ground truth may be in another (a SemanticKITTI
model labelling a nuScenes log). Scores and exports across the two go through a mapping file in
package data, found by the pair of label-map names::

    dsnet_core/data/<source name>-to-<target name>.yaml
    source: semantic-kitti
    target: panoptic-nuscenes
    classes:            # source train class name -> target raw id
      car: 17

Never silent: a pair without a file is a :class:`~dsnet_core.errors.ConfigError` naming the file it
looked for, and whoever maps records :meth:`ClassMapping.record` (file, sha256, the classes and
which target classes no source class reaches).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from importlib import resources

import numpy as np
import yaml

from dsnet_core.errors import ConfigError
from dsnet_core.labels import LabelMap


def mapping_file(source: str, target: str) -> str:
    """The package-data file name of the mapping from label map ``source`` to ``target``."""
    return f"{source}-to-{target}.yaml"


@dataclass(frozen=True)
class ClassMapping:
    """A mapping from a source label map's train classes to a target label map's raw ids.

    Attributes:
        source: the predictions' label map (the model's).
        target: the ground truth's label map.
        file: the mapping's package-data file name.
        sha256: the file's sha256 (hex).
        by_train: ``(source classes,) int64`` target raw id of each source train id.
    """

    source: LabelMap
    target: LabelMap
    file: str
    sha256: str
    by_train: np.ndarray

    def raw_lut(self) -> np.ndarray:
        """``(65536,) int64``: source raw semantic id -> target raw id (unknown raw ids -> the
        target's raw id of source class 0)."""
        return self.by_train[np.maximum(self.source.lut(1 << 16, fill=0), 0)]

    def target_train(self) -> np.ndarray:
        """``(source classes,) int64``: the target train class of each source train class."""
        return self.target.lut(self.target.max_raw_id + 1, fill=0).astype(np.int64)[self.by_train]

    def map_labels(self, labels: np.ndarray) -> np.ndarray:
        """``(N,) uint32`` source ``raw | instance << 16`` -> target ``raw | instance << 16``
        (instance ids kept)."""
        labels = np.asarray(labels, dtype=np.uint32)
        raw = self.raw_lut()[(labels & np.uint32(0xFFFF)).astype(np.int64)].astype(np.uint32)
        return raw | (labels & np.uint32(0xFFFF0000))

    @property
    def expressible(self) -> tuple[int, ...]:
        """Target train ids (not ignored) that some source class maps to, ascending."""
        reached = set(self.target_train()[1:].tolist())
        return tuple(
            c for c in range(self.target.num_classes) if c in reached and c not in self.target.ignore
        )

    @property
    def unexpressible(self) -> tuple[int, ...]:
        """Target train ids (not ignored) no source class reaches: a model of the source classes
        cannot predict them."""
        return tuple(
            c
            for c in range(self.target.num_classes)
            if c not in self.target.ignore and c not in self.expressible
        )

    def record(self) -> dict[str, object]:
        """What a run or a score report records of the mapping (JSON-ready)."""
        names = self.target.class_names
        train = self.target_train()
        return {
            "file": self.file,
            "sha256": self.sha256,
            "source": self.source.name,
            "target": self.target.name,
            "classes": {
                self.source.class_names[k]: names[int(train[k])] for k in range(self.source.num_classes)
            },
            "unexpressible": [names[c] for c in self.unexpressible],
        }


def class_mapping(source: LabelMap, target: LabelMap) -> ClassMapping:
    """The mapping from ``source``'s classes to ``target``'s, from package data.

    Raises:
        ConfigError: no mapping file for the pair; a class the source lacks; a target raw id the
            target lacks; a source thing class mapped to a target stuff class; a source class left
            out.
    """
    name = mapping_file(source.name, target.name)
    res = resources.files("dsnet_core.data").joinpath(name)
    if not res.is_file():
        raise ConfigError(
            f"the model predicts {source.name!r} classes and the ground truth is in {target.name!r}: "
            f"no class mapping dsnet_core/data/{name} between them"
        )
    text = res.read_text()
    data = yaml.safe_load(text) or {}
    where = f"dsnet_core/data/{name}"
    if (data.get("source"), data.get("target")) != (source.name, target.name):
        raise ConfigError(f"{where}: says source {data.get('source')!r}, target {data.get('target')!r}")
    classes = data.get("classes") or {}
    ids = {n: i for i, n in enumerate(source.class_names)}
    target_thing = target.is_thing()
    target_lut = target.lut(max(target.max_raw_id + 1, 1), fill=-1)
    by_train = np.full(source.num_classes, -1, dtype=np.int64)
    for cls, raw in classes.items():
        if cls not in ids:
            raise ConfigError(f"{where}: {cls!r} is not a {source.name} class")
        raw = int(raw)
        if not 0 <= raw < target_lut.size or target_lut[raw] < 0:
            raise ConfigError(f"{where}: {cls}: {raw} is not a {target.name} raw id")
        if ids[cls] in source.things and not target_thing[target_lut[raw]]:
            raise ConfigError(f"{where}: thing class {cls} mapped to a stuff class ({target.labels[raw]})")
        by_train[ids[cls]] = raw
    missing = [source.class_names[k] for k in np.flatnonzero(by_train < 0)]
    if missing:
        raise ConfigError(f"{where}: no target class for {', '.join(missing)}")
    digest = hashlib.sha256(text.encode()).hexdigest()
    return ClassMapping(source, target, name, digest, by_train)
