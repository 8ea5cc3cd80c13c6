"""nuScenes JSON tables, checked as the reader uses them: every record of a table is an object
with the fields the reader reads (:data:`FIELDS`), tokens are texts that no two records share, the
LiDAR ``sample_data`` records have fields of the right types, and a pose record holds three finite
translation values and a unit quaternion (w, x, y, z). Anything else is a
:class:`~dsnet_core.errors.TableFormatError` naming the table file and the record (its position,
and its token where it has one).

What is checked for every record when a table loads is only the fields' presence (0.3 µs a record;
``v1.0-trainval``'s 2.6 M ``sample_data`` records take ~10 s to parse as JSON); types are checked
on the records the reader uses.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from dsnet_core.errors import TableFormatError
from dsnet_core.io.geometry import pose_matrix

TABLES = ("scene", "sample", "sample_data", "ego_pose", "calibrated_sensor", "sensor", "category")
FIELDS = {  # the fields this reader uses, per table: every record must have them
    "scene": ("token", "name"),
    "sample": ("token", "scene_token"),
    "sample_data": (
        "token",
        "sample_token",
        "ego_pose_token",
        "calibrated_sensor_token",
        "timestamp",
        "is_key_frame",
        "filename",
    ),
    "ego_pose": ("token", "translation", "rotation"),
    "calibrated_sensor": ("token", "sensor_token", "translation", "rotation"),
    "sensor": ("token", "channel"),
    "category": ("name",),
    "panoptic": ("sample_data_token", "filename"),
    "lidarseg": ("sample_data_token", "filename"),
}
LINKS = {"sample": ("scene_token",), "calibrated_sensor": ("sensor_token",)}
"""Fields of small tables that name another table's record: texts in every record."""
LIDAR_SAMPLE_DATA = (  # the types of the fields of the LiDAR sample_data records, checked as read
    ("token", str),
    ("sample_token", str),
    ("ego_pose_token", str),
    ("timestamp", (int, float)),
    ("is_key_frame", bool),
    ("filename", str),
)
UNIT_TOL = 0.01
"""How far a rotation quaternion's norm may be from 1 (rounded or float32 values are well within;
a zero or garbage quaternion is not)."""


def load_table(path: Path, name: str, required: bool) -> list[dict] | None:
    """The records of one table (None for a missing optional one).

    Raises:
        TableFormatError: missing (when required), not JSON, not a list, a record that is not an
            object or lacks a field of :data:`FIELDS`.
    """
    if not path.is_file():
        if required:
            raise TableFormatError(path, "table is missing")
        return None
    try:
        table = json.loads(path.read_bytes())
    except (OSError, ValueError) as exc:
        raise TableFormatError(path, f"not a readable JSON table: {exc}") from exc
    if not isinstance(table, list):
        raise TableFormatError(path, "expected a JSON list of records")
    fields = frozenset(FIELDS.get(name, ()))
    for i, rec in enumerate(table):
        if type(rec) is not dict or not rec.keys() >= fields:
            if not isinstance(rec, dict):
                raise TableFormatError(
                    path, f"record {i} is a JSON {_json_type(rec)} ({short(rec)}), expected an object"
                )
            missing = ", ".join(repr(k) for k in FIELDS[name] if k not in rec)
            raise TableFormatError(path, f"record {i}{_token_of(rec)} has no {missing}")
    return table


def index_table(
    path: Path, table: list[dict], key: str = "token", texts: tuple[str, ...] = ()
) -> dict[str, dict]:
    """``{record[key]: record}`` of a table read from ``path``.

    Args:
        texts: other fields that must be texts in every record (tokens the reader looks up).

    Raises:
        TableFormatError: a key or ``texts`` field that is not a text, or a key two records share
            (naming both).
    """
    try:
        out = {rec[key]: rec for rec in table}
    except TypeError:  # a list or an object as the key
        out = None
    if out is None or (out and set(map(type, out)) != {str}):
        i = next(i for i, rec in enumerate(table) if type(rec[key]) is not str)
        raise TableFormatError(path, f"record {i} has {key} {short(table[i][key])}, expected a text")
    if len(out) != len(table):
        seen: dict[str, int] = {}
        for i, rec in enumerate(table):
            if rec[key] in seen:
                raise TableFormatError(
                    path, f"records {seen[rec[key]]} and {i} have the same {key} {rec[key]!r}"
                )
            seen[rec[key]] = i
    for field in texts:
        for i, rec in enumerate(table):
            if type(rec[field]) is not str:
                raise TableFormatError(
                    path, f"record {i}{_token_of(rec)} has {field} {short(rec[field])}, expected a text"
                )
    return out


def index_tables(folder: Path, tables: dict[str, list[dict]]) -> dict[str, dict[str, dict]]:
    """Every table of :data:`TABLES` with tokens, indexed by token (:func:`index_table`, with the
    links the reader follows checked as texts); scene names, which name sequences, must differ too."""
    out = {
        name: index_table(folder / f"{name}.json", tables[name], texts=LINKS.get(name, ()))
        for name in TABLES
        if "token" in FIELDS[name]
    }
    index_table(folder / "scene.json", tables["scene"], "name")
    return out


def is_lidar_record(path: Path, i: int, sd: dict, lidar_cal: set[str]) -> bool:
    """Whether ``sample_data`` record ``i`` belongs to the LiDAR channel (its calibrated sensor is
    in ``lidar_cal``), checking the types of the fields the reader uses when it does.

    Raises:
        TableFormatError: a field of the wrong type (naming ``path``, the record and the field).
    """
    cal = sd["calibrated_sensor_token"]
    if type(cal) is not str:
        raise TableFormatError(
            path, f"record {i}{_token_of(sd)} has calibrated_sensor_token {short(cal)}, expected a text"
        )
    if cal not in lidar_cal:
        return False
    for key, kind in LIDAR_SAMPLE_DATA:
        if not isinstance(sd[key], kind) or (kind is not bool and isinstance(sd[key], bool)):
            raise TableFormatError(
                path, f"record {i}{_token_of(sd)} has {key} {short(sd[key])}, expected {_kind(kind)}"
            )
    return True


def rigid(path: Path, rec: dict) -> np.ndarray:
    """float64 ``(4, 4)`` of a record's ``translation`` (metres) and ``rotation`` (w, x, y, z).

    Raises:
        TableFormatError: not 3 finite translation values, not 4 finite rotation values, or a
            rotation whose norm is not within :data:`UNIT_TOL` of 1 (a zero quaternion).
    """
    t, q = _numbers(rec["translation"], 3), _numbers(rec["rotation"], 4)
    problem = None
    if t is None:
        problem = f"translation {short(rec['translation'])} is not 3 finite numbers"
    elif q is None:
        problem = f"rotation {short(rec['rotation'])} is not 4 finite numbers (w, x, y, z)"
    elif abs(np.linalg.norm(q) - 1) > UNIT_TOL:
        problem = f"rotation {q.tolist()} is not a unit quaternion (norm {np.linalg.norm(q):.6g})"
    if problem is not None:
        raise TableFormatError(path, f"record {rec['token']!r}: {problem}")
    return pose_matrix(t, q)


def short(value: object, limit: int = 60) -> str:
    """A JSON value as text, cut to ``limit`` characters."""
    text = (
        json.dumps(value) if isinstance(value, str | int | float | bool | list | dict | None) else repr(value)
    )
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _json_type(value: object) -> str:
    names = {str: "string", int: "number", float: "number", bool: "boolean", list: "list", type(None): "null"}
    return names.get(type(value), type(value).__name__)


def _token_of(rec: dict) -> str:
    token = rec.get("token")
    return f" (token {token!r})" if isinstance(token, str) else ""


def _kind(kind: type | tuple[type, ...]) -> str:
    return {str: "a text", bool: "true or false"}.get(kind, "a number")  # type: ignore[arg-type]


def _numbers(value: object, n: int) -> np.ndarray | None:
    """float64 ``(n,)`` of a JSON list of ``n`` finite numbers, else None."""
    if not isinstance(value, list) or len(value) != n:
        return None
    if not all(isinstance(v, int | float) and not isinstance(v, bool) for v in value):
        return None
    out = np.asarray(value, dtype=np.float64)
    return out if np.isfinite(out).all() else None
