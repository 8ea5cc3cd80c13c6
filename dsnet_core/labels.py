"""Label maps, loaded from the YAML files in package data (the single source of truth).

Everything else (lookup tables, thing/stuff masks, names) is derived here.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cache
from importlib import resources
from pathlib import Path

import numpy as np
import yaml

from dsnet_core.errors import ConfigError

_BUILTIN = {
    "semantic-kitti": "semantic-kitti.yaml",
    "panoptic-nuscenes": "panoptic-nuscenes.yaml",
}


@dataclass(frozen=True)
class LabelMap:
    """A dataset's label definitions.

    Attributes:
        name: dataset name.
        labels: raw id -> raw class name.
        learning_map: raw id -> train id (0 = ignore).
        learning_map_inv: train id -> raw id (for writing predictions).
        class_names: train id -> name (index 0 is the ignore class).
        things: train ids of thing classes.
        stuff: train ids of stuff classes.
        min_points: the benchmark's minimum segment size for unmatched segments.
        split: split name -> list of sequence numbers.
        color_map: raw id -> (b, g, r).
    """

    name: str
    labels: dict[int, str]
    learning_map: dict[int, int]
    learning_map_inv: dict[int, int]
    class_names: tuple[str, ...]
    things: tuple[int, ...]
    stuff: tuple[int, ...]
    min_points: int
    split: dict[str, list[int]] = field(default_factory=dict)
    color_map: dict[int, tuple[int, int, int]] = field(default_factory=dict)
    source: str = ""

    @property
    def num_classes(self) -> int:
        """Number of train ids including the ignore class 0."""
        return len(self.class_names)

    @property
    def max_raw_id(self) -> int:
        return max(self.learning_map)

    def lut(self, size: int | None = None, fill: int = -1) -> np.ndarray:
        """Raw id -> train id lookup table, ``(size,) int32``.

        Args:
            size: table length (default ``max_raw_id + 1``; ``1 << 16`` covers every raw id).
            fill: train id of raw ids the map does not know (-1 marks them; 0 ignores them).
        """
        table = np.full(self.max_raw_id + 1 if size is None else size, fill, dtype=np.int32)
        for raw, train in self.learning_map.items():
            if 0 <= raw < table.size:
                table[raw] = train
        return table

    def inv_lut(self) -> np.ndarray:
        """Train id -> raw id lookup table, ``(num_classes,) uint32``."""
        table = np.zeros(self.num_classes, dtype=np.uint32)
        for train, raw in self.learning_map_inv.items():
            table[train] = raw
        return table

    def is_thing(self) -> np.ndarray:
        """``(num_classes,) bool``: True for thing train ids."""
        mask = np.zeros(self.num_classes, dtype=bool)
        mask[list(self.things)] = True
        return mask

    def to_train(self, raw: np.ndarray) -> np.ndarray:
        """Map raw semantic ids ``(N,)`` to train ids ``(N,) int32``.

        Raises:
            ValueError: if a raw id is not in the map (callers add the file name).
        """
        raw = np.asarray(raw, dtype=np.int64)
        lut = self.lut()
        if raw.size and (raw.max() > self.max_raw_id or raw.min() < 0):
            bad = np.unique(raw[(raw > self.max_raw_id) | (raw < 0)])
            raise ValueError(f"raw semantic ids not in the {self.name} label map: {bad[:10].tolist()}")
        out = lut[raw]
        if (out < 0).any():
            bad = np.unique(raw[out < 0])
            raise ValueError(f"raw semantic ids not in the {self.name} label map: {bad[:10].tolist()}")
        return out

    def to_raw(self, train: np.ndarray) -> np.ndarray:
        """Map train ids ``(N,)`` to raw ids ``(N,) uint32`` through ``learning_map_inv``."""
        return self.inv_lut()[np.asarray(train, dtype=np.int64)]


def _int_keys(d: dict, path: str, key: str) -> dict[int, object]:
    try:
        return {int(k): v for k, v in d.items()}
    except (TypeError, ValueError, AttributeError) as exc:
        raise ConfigError(f"{path}: '{key}' must map integer ids to values") from exc


def parse_label_map(data: dict, source: str = "<dict>") -> LabelMap:
    """Build a :class:`LabelMap` from a parsed SemanticKITTI-style YAML mapping."""
    for key in ("labels", "learning_map"):
        if key not in data:
            raise ConfigError(f"{source}: missing required key '{key}'")
    labels = {k: str(v) for k, v in _int_keys(data["labels"], source, "labels").items()}
    learning_map = {k: int(v) for k, v in _int_keys(data["learning_map"], source, "learning_map").items()}
    n_train = max(learning_map.values()) + 1
    if "learning_map_inv" in data:
        inv = {k: int(v) for k, v in _int_keys(data["learning_map_inv"], source, "learning_map_inv").items()}
    else:
        inv = {}
        for raw, train in sorted(learning_map.items()):
            inv.setdefault(train, raw)
    names_src = data.get("challenge_labels")
    if names_src is not None:
        names = _int_keys(names_src, source, "challenge_labels")
        class_names = tuple(str(names[i]) for i in range(n_train))
    else:
        class_names = tuple(
            "unlabeled" if i == 0 else labels.get(inv.get(i, -1), f"class_{i}") for i in range(n_train)
        )
    things = tuple(int(t) for t in data.get("things", range(1, 9)))
    stuff = tuple(int(s) for s in data.get("stuff", [i for i in range(1, n_train) if i not in things]))
    split = {str(k): [int(s) for s in v] for k, v in (data.get("split") or {}).items()}
    color_map = {
        k: tuple(int(c) for c in v)
        for k, v in _int_keys(data.get("color_map") or {}, source, "color_map").items()
    }
    return LabelMap(
        name=str(data.get("name", Path(source).stem)),
        labels=labels,
        learning_map=learning_map,
        learning_map_inv=inv,
        class_names=class_names,
        things=things,
        stuff=stuff,
        min_points=int(data.get("min_points", 50)),
        split=split,
        color_map=color_map,  # type: ignore[arg-type]
        source=source,
    )


def load_label_map(name_or_path: str | Path = "semantic-kitti") -> LabelMap:
    """Load a bundled label map by name (``semantic-kitti``, ``panoptic-nuscenes``) or a YAML file."""
    key = str(name_or_path)
    if key in _BUILTIN:
        return _load_builtin(key)
    path = Path(key)
    if not path.is_file():
        raise ConfigError(f"{path}: label map file not found (bundled: {sorted(_BUILTIN)})")
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML: {exc}") from exc
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a mapping at top level")
    return parse_label_map(data, str(path))


@cache
def _load_builtin(key: str) -> LabelMap:
    text = resources.files("dsnet_core").joinpath("data", _BUILTIN[key]).read_text()
    return parse_label_map(yaml.safe_load(text), f"dsnet_core/data/{_BUILTIN[key]}")
