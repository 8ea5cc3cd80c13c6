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
        ignore: train ids not scored (``learning_ignore``; default: class 0).
        track_groups: groups of thing train ids that a tracker may associate with each other
            (YAML ``track_groups``); a thing class in no group forms a group of its own.
        ground: stuff train ids of the ground surface (YAML ``ground``: road, sidewalk, terrain, ...),
            the classes a ground segmentation's "ground" stands for; empty when the map says nothing.
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
    ignore: tuple[int, ...] = (0,)
    track_groups: tuple[tuple[int, ...], ...] = ()
    ground: tuple[int, ...] = ()

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

    def track_group_of(self) -> np.ndarray:
        """``(num_classes,) int64``: the association group of each train id (``track_groups`` in
        order, then one group per remaining class)."""
        group = np.full(self.num_classes, -1, dtype=np.int64)
        for g, classes in enumerate(self.track_groups):
            group[list(classes)] = g
        rest = np.flatnonzero(group < 0)
        group[rest] = len(self.track_groups) + np.arange(rest.size)
        return group

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

    def unknown_raw_ids(self, raw: np.ndarray) -> np.ndarray:
        """Sorted distinct raw semantic ids of ``raw`` ``(N,)`` that ``learning_map`` does not have."""
        ids = np.unique(np.asarray(raw, dtype=np.int64))
        known = (ids >= 0) & (ids <= self.max_raw_id)
        known[known] = self.lut()[ids[known]] >= 0
        return ids[~known]

    def to_raw(self, train: np.ndarray) -> np.ndarray:
        """Map train ids ``(N,)`` to raw ids ``(N,) uint32`` through ``learning_map_inv``."""
        return self.inv_lut()[np.asarray(train, dtype=np.int64)]


def _int_keys(d: dict, path: str, key: str) -> dict[int, object]:
    try:
        return {int(k): v for k, v in d.items()}
    except (TypeError, ValueError, AttributeError) as exc:
        raise ConfigError(f"{path}: '{key}' must map integer ids to values") from exc


def _train_ids(learning_map: dict[int, int], inv: dict[int, int] | None, source: str) -> int:
    """The number of train ids, checking that they run 0..C-1 without gaps.

    With ``learning_map_inv`` its keys are the train ids; without it the values of ``learning_map``
    are. A train id outside that set (a typo such as ``10: 999``) is an error naming the raw id.
    """
    bad_raw = [k for k in learning_map if not 0 <= k <= 0xFFFF]
    if bad_raw:
        raise ConfigError(f"{source}: learning_map has raw id {bad_raw[0]}, outside 0..65535")
    ids = set(inv) if inv is not None else set(learning_map.values())
    n = max(ids) + 1 if ids else 0
    missing = sorted(set(range(n)) - ids)
    if not ids or min(ids) < 0 or missing:
        where = "learning_map_inv's keys" if inv is not None else "learning_map's values"
        hint = f"; missing {missing[:10]}" if missing else ""
        if inv is None and missing:
            top = max(ids)
            raws = sorted(k for k, v in learning_map.items() if v == top)
            hint += f" (learning_map sends raw id {raws[0]} to train id {top})"
        raise ConfigError(f"{source}: {where} must be the train ids 0..C-1 without gaps{hint}")
    if inv is not None:
        unknown = sorted((k, v) for k, v in learning_map.items() if v not in ids)
        if unknown:
            raw, train = unknown[0]
            raise ConfigError(
                f"{source}: learning_map sends raw id {raw} to train id {train}, which learning_map_inv "
                f"does not have (train ids 0..{n - 1})"
            )
    return n


def _ids_in_range(values, n: int, source: str, key: str) -> tuple[int, ...]:
    try:
        ids = tuple(int(v) for v in values)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{source}: '{key}' must be a list of train ids") from exc
    bad = [i for i in ids if not 0 <= i < n]
    if bad:
        raise ConfigError(f"{source}: '{key}' has train id {bad[0]}, outside 0..{n - 1}")
    return ids


def _learning_ignore(value, n: int, source: str) -> tuple[int, ...]:
    """Train ids of ``learning_ignore``: a mapping ``{id: bool}`` (SemanticKITTI) or a list of ids."""
    if value is None:
        return (0,)
    if isinstance(value, dict):
        ids = [k for k, v in _int_keys(value, source, "learning_ignore").items() if v]
    elif isinstance(value, list | tuple):
        ids = list(value)
    else:
        raise ConfigError(f"{source}: 'learning_ignore' must map train ids to true/false or list train ids")
    return tuple(sorted(set(_ids_in_range(ids, n, source, "learning_ignore")))) or (0,)


def parse_label_map(data: dict, source: str = "<dict>") -> LabelMap:
    """Build a :class:`LabelMap` from a parsed SemanticKITTI-style YAML mapping.

    Raises:
        ConfigError: a required key is missing, train ids are not 0..C-1 without gaps (a
            ``learning_map`` value such as 999), a thing/stuff/ignore id is out of range, or a
            value has the wrong type; the message starts with ``source``.
    """
    for key in ("labels", "learning_map"):
        if key not in data:
            raise ConfigError(f"{source}: missing required key '{key}'")
    labels = {k: str(v) for k, v in _int_keys(data["labels"], source, "labels").items()}
    learning_map = _int_values(
        _int_keys(data["learning_map"], source, "learning_map"), source, "learning_map"
    )
    inv = None
    if "learning_map_inv" in data:
        inv = _int_values(
            _int_keys(data["learning_map_inv"], source, "learning_map_inv"), source, "learning_map_inv"
        )
    n_train = _train_ids(learning_map, inv, source)
    if inv is None:
        inv = {}
        for raw, train in sorted(learning_map.items()):
            inv.setdefault(train, raw)
    names_src = data.get("challenge_labels")
    if names_src is not None:
        names = _int_keys(names_src, source, "challenge_labels")
        missing = [i for i in range(n_train) if i not in names]
        if missing:
            raise ConfigError(f"{source}: 'challenge_labels' has no name for train id {missing[0]}")
        class_names = tuple(str(names[i]) for i in range(n_train))
    else:
        class_names = tuple(
            "unlabeled" if i == 0 else labels.get(inv.get(i, -1), f"class_{i}") for i in range(n_train)
        )
    things = _ids_in_range(data.get("things", range(1, min(9, n_train))), n_train, source, "things")
    stuff = _ids_in_range(
        data.get("stuff", [i for i in range(1, n_train) if i not in things]), n_train, source, "stuff"
    )
    try:
        split = {str(k): [int(s) for s in v] for k, v in (data.get("split") or {}).items()}
        color_map = {
            k: tuple(int(c) for c in v)
            for k, v in _int_keys(data.get("color_map") or {}, source, "color_map").items()
        }
        min_points = int(data.get("min_points", 50))
    except (TypeError, ValueError, AttributeError) as exc:
        raise ConfigError(f"{source}: 'split', 'color_map' or 'min_points' is malformed: {exc}") from exc
    groups = _track_groups(data.get("track_groups") or [], things, source)
    ground = _ids_in_range(data.get("ground") or [], n_train, source, "ground")
    if set(ground) & set(things):
        raise ConfigError(f"{source}: 'ground' names thing ids {sorted(set(ground) & set(things))}")
    return LabelMap(
        name=str(data.get("name", Path(source).stem)),
        labels=labels,
        learning_map=learning_map,
        learning_map_inv=inv,
        class_names=class_names,
        things=things,
        stuff=stuff,
        min_points=min_points,
        split=split,
        color_map=color_map,  # type: ignore[arg-type]
        source=source,
        ignore=_learning_ignore(data.get("learning_ignore"), n_train, source),
        track_groups=groups,
        ground=ground,
    )


def _int_values(d: dict[int, object], source: str, key: str) -> dict[int, int]:
    try:
        return {k: int(v) for k, v in d.items()}  # type: ignore[call-overload]
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{source}: '{key}' must map integer ids to integer ids") from exc


def _track_groups(raw: object, things: tuple[int, ...], source: str) -> tuple[tuple[int, ...], ...]:
    """Validate ``track_groups``: lists of thing train ids, each id in at most one group."""
    try:
        groups = tuple(tuple(int(c) for c in g) for g in raw)  # type: ignore[union-attr]
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{source}: 'track_groups' must be a list of lists of train ids") from exc
    flat = [c for g in groups for c in g]
    if len(flat) != len(set(flat)):
        raise ConfigError(f"{source}: a class appears in more than one of 'track_groups' {groups}")
    if not set(flat) <= set(things):
        raise ConfigError(
            f"{source}: 'track_groups' name ids that are not things: {sorted(set(flat) - set(things))}"
        )
    return groups


def builtin_label_maps() -> list[str]:
    """Names of the bundled label maps, sorted."""
    return sorted(_BUILTIN)


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
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path}: not a text file: {exc}") from exc
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML: {exc}") from exc
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a mapping at top level")
    return parse_label_map(data, str(path))


@cache
def _load_builtin(key: str) -> LabelMap:
    text = resources.files("dsnet_core").joinpath("data", _BUILTIN[key]).read_text()
    return parse_label_map(yaml.safe_load(text), f"dsnet_core/data/{_BUILTIN[key]}")


def class_map_of(label_map: LabelMap) -> dict:
    """The part of a label map a model depends on (stored in, and checked against, a model card):
    name, class names, thing ids and train → raw ids."""
    return {
        "name": label_map.name,
        "class_names": list(label_map.class_names),
        "things": list(label_map.things),
        "learning_map_inv": {str(k): int(v) for k, v in sorted(label_map.learning_map_inv.items())},
    }


def label_map_from_class_map(class_map: dict) -> LabelMap:
    """The label map of a model card's class map: the bundled map of that name when it matches
    exactly, else a map built from the class map alone (its raw ids are the ``learning_map_inv``
    values, each naming its class).

    Raises:
        ConfigError: the class map lacks a field or its ids do not fit its class names.
    """
    try:
        name = str(class_map["name"])
        names = tuple(str(n) for n in class_map["class_names"])
        things = tuple(int(t) for t in class_map["things"])
        inv = {int(k): int(v) for k, v in class_map["learning_map_inv"].items()}
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise ConfigError(f"model card class map is incomplete or malformed: {exc!r}") from exc
    normal = {
        "name": name,
        "class_names": list(names),
        "things": list(things),
        "learning_map_inv": {str(k): v for k, v in sorted(inv.items())},
    }
    if name in _BUILTIN and class_map_of(_load_builtin(name)) == normal:
        return _load_builtin(name)
    if any(not 0 <= t < len(names) for t in [*things, *inv]):
        raise ConfigError(f"model card class map {name!r}: ids outside its {len(names)} classes")
    return LabelMap(
        name=name,
        labels={raw: names[train] for train, raw in inv.items()},
        learning_map={raw: train for train, raw in sorted(inv.items(), reverse=True)},
        learning_map_inv=inv,
        class_names=names,
        things=things,
        stuff=tuple(i for i in range(1, len(names)) if i not in things),
        min_points=50,
        source=f"model card class map {name!r}",
    )
