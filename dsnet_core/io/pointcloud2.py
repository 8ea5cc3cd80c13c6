"""``sensor_msgs/PointCloud2`` messages -> points, fields found by name and datatype.

A cloud is ``height × width`` points (height 1: unorganised; > 1: organised, rows ``row_step``
bytes apart), each ``point_step`` bytes holding the named fields at their offsets; its data is
exactly ``row_step × height`` bytes (a cloud whose layout covers part of its data is an error,
not a partial read). x, y, z must
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


def check_layout(
    data: np.ndarray, height: int, width: int, row_step: int, point_step: int, where: str | Path
) -> None:
    """A cloud's data must be ``row_step × height`` bytes, each row holding ``width`` points of
    ``point_step`` bytes (``width × point_step ≤ row_step``) and then only zero bytes (alignment
    padding): data past ``width`` points that is not zero is points the layout does not count.

    Args:
        data: uint8 ``(size,)``, the message's data.

    Raises:
        BagFormatError: naming ``where``, the layout's numbers and what the data holds.
    """
    used = width * point_step
    if used > row_step:
        raise BagFormatError(
            where,
            f"cloud rows of width {width} × point_step {point_step} = {used} bytes do not fit in row_step "
            f"{row_step}",
        )
    if data.size != height * row_step:
        held = f" ({data.size // row_step} rows)" if row_step and data.size % row_step == 0 else ""
        raise BagFormatError(
            where,
            f"cloud data has {data.size} bytes{held}, its layout height {height} × row_step {row_step} = "
            f"{height * row_step} ({height} × {width} points): the layout and the data disagree",
        )
    if used < row_step and data.size and data.reshape(height, row_step)[:, used:].any():
        room = f" (room for {(row_step - used) // point_step} more points)" if point_step else ""
        raise BagFormatError(
            where,
            f"cloud rows hold {row_step - used} bytes past width {width} × point_step {point_step}{room} "
            "that are not zero padding: the layout covers part of the data",
        )


def decode_cloud(msg: Any, where: str | Path, intensity_field: str | None = None) -> Cloud:
    """Decode a deserialised PointCloud2 message.

    Args:
        where: the bag and message, for error messages.
        intensity_field: the intensity field's name (default: ``intensity``, else ``reflectivity``).

    Raises:
        BagFormatError: x/y/z missing or not float, data of another length than the layout's
            ``row_step × height`` (:func:`check_layout`), a named intensity field missing.
        IntensityFormatError: an intensity field of an unsupported datatype.
    """
    dt = cloud_dtype(msg, where)
    h, w = int(msg.height), int(msg.width)
    row_step, point_step = int(msg.row_step), int(msg.point_step)
    data = np.asarray(msg.data, dtype=np.uint8)
    check_layout(data, h, w, row_step, point_step, where)
    pts = np.ndarray((h, w), dtype=dt, buffer=data, strides=(row_step, point_step)).reshape(-1)
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
