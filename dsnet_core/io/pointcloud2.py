"""``sensor_msgs/PointCloud2`` messages -> points, fields found by name and datatype.

A cloud is ``height × width`` points (height 1: unorganised; > 1: organised, rows ``row_step``
bytes apart), each ``point_step`` bytes holding the named fields at their offsets. x, y, z must
be FLOAT32 or FLOAT64; the intensity is the field named by the caller, else the first of
``intensity`` and ``reflectivity`` present (UINT8, UINT16 or a float; any other datatype is an
error). Points whose x, y or z is NaN or inf (no return) are dropped and counted; finite points
beyond :data:`dsnet_core.io.checks.MAX_COORD_M` are a corrupt cloud (an error).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from dsnet_core.errors import BagFormatError
from dsnet_core.io.checks import check_points
from dsnet_core.io.intensity import check_column

# sensor_msgs/PointField datatypes
DATATYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}
INTENSITY_FIELDS = ("intensity", "reflectivity")


@dataclass
class Cloud:
    """A decoded cloud: ``xyz`` float32 ``(N, 3)`` metres (sensor frame), ``intensity`` ``(N,)`` as
    stored or None, the intensity field's name, how many NaN/inf returns were dropped and ``keep``,
    bool ``(M,)`` over the message's points, when any was (else None)."""

    xyz: np.ndarray
    intensity: np.ndarray | None
    field: str | None
    dropped: int
    keep: np.ndarray | None = None


def cloud_dtype(msg: Any, where: str | Path) -> np.dtype:
    """The structured dtype of one point (itemsize ``point_step``; fields with count 1 only)."""
    order = ">" if msg.is_bigendian else "<"
    names, formats, offsets = [], [], []
    for f in msg.fields:
        if f.datatype not in DATATYPES:
            raise BagFormatError(where, f"field {f.name!r} has unknown PointField datatype {f.datatype}")
        if f.count != 1 or f.name in names:
            continue
        names.append(f.name)
        formats.append(order + DATATYPES[f.datatype])
        offsets.append(f.offset)
    try:
        return np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": msg.point_step})
    except ValueError as exc:
        raise BagFormatError(where, f"fields do not fit in point_step {msg.point_step}: {exc}") from exc


def decode_cloud(msg: Any, where: str | Path, intensity_field: str | None = None) -> Cloud:
    """Decode a deserialised PointCloud2 message.

    Args:
        where: the bag and message, for error messages.
        intensity_field: the intensity field's name (default: ``intensity``, else ``reflectivity``).

    Raises:
        BagFormatError: x/y/z missing or not float, data shorter than the layout, a named
            intensity field missing.
        IntensityFormatError: an intensity field of an unsupported datatype.
    """
    dt = cloud_dtype(msg, where)
    h, w = int(msg.height), int(msg.width)
    data = np.asarray(msg.data, dtype=np.uint8)
    need = 0 if h * w == 0 else (h - 1) * int(msg.row_step) + w * int(msg.point_step)
    if data.size < need:
        raise BagFormatError(where, f"cloud data has {data.size} bytes, its {h}×{w} layout needs {need}")
    pts = np.ndarray((h, w), dtype=dt, buffer=data, strides=(int(msg.row_step), int(msg.point_step))).reshape(
        -1
    )
    for c in "xyz":
        if c not in dt.names:
            raise BagFormatError(where, f"cloud has no {c} field (fields: {', '.join(dt.names)})")
        if dt[c].kind != "f":
            raise BagFormatError(where, f"field {c} has datatype {dt[c]}, expected FLOAT32 or FLOAT64")
    xyz = np.empty((pts.size, 3), dtype=np.float32)
    for i, c in enumerate("xyz"):
        xyz[:, i] = pts[c]
    names = (intensity_field,) if intensity_field else INTENSITY_FIELDS
    field = next((n for n in names if n in dt.names), None)
    if intensity_field and field is None:
        raise BagFormatError(where, f"cloud has no field {intensity_field!r} (fields: {', '.join(dt.names)})")
    intensity = None
    if field is not None:
        intensity = pts[field].astype(dt[field].newbyteorder("="))
        check_column(intensity, where, field)
    keep = np.isfinite(xyz).all(axis=1)
    dropped = int(keep.size - keep.sum())
    if dropped:
        xyz = xyz[keep]
        intensity = None if intensity is None else intensity[keep]
    check_points(where, xyz)
    return Cloud(xyz, intensity, field, dropped, keep if dropped else None)
