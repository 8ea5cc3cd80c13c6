"""Single-scan point files: ``.bin``, ``.npy``, ``.npz``, ``.pcd``, ``.ply``, ``.las``, ``.laz``.

Each decoder returns :class:`Points`: float32 ``(N, 3)`` x, y, z in metres and the intensity
column as stored (its convention is decided by :mod:`dsnet_core.io.intensity`), or None when
the file has none. Fields are found by name, case-insensitively: x, y, z, and the first of
:data:`INTENSITY_NAMES` present.

``.bin``: float32 rows of 4 (x, y, z, intensity: KITTI) or 5 (x, y, z, intensity, ring:
nuScenes) columns; :func:`bin_columns` states the detection rule.
``.npy``: a plain ``(N, 3|4|5)`` array (same column meaning) or a structured array with named
fields. ``.npz``: an array ``points`` (or ``scan``) as for ``.npy``, or arrays ``x``, ``y``, ``z``
and an optional intensity array. ``.ply``: the ``vertex`` element (plyfile). ``.las``/``.laz``:
scaled coordinates (scale factors of 0 or not finite are refused) and the uint16 ``intensity``
(laspy, lazrs for LAZ).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dsnet_core.errors import MissingExtraError, PointFileFormatError
from dsnet_core.io.asciinum import parse_numbers
from dsnet_core.io.checks import check_points, drop_no_returns
from dsnet_core.io.intensity import check_column
from dsnet_core.io.pcd import read_pcd

INTENSITY_NAMES = ("intensity", "remission", "reflectivity", "scalar_intensity", "i")
SUFFIXES = (".bin", ".npy", ".npz", ".pcd", ".ply", ".las", ".laz")


@dataclass
class Points:
    """One decoded scan: ``xyz`` float32 ``(N, 3)`` metres; ``intensity`` ``(N,)`` as stored or None;
    ``keep`` bool ``(M,)`` over the file's points when points without a return (NaN x/y/z) were
    dropped, else None."""

    xyz: np.ndarray
    intensity: np.ndarray | None
    field: str | None = None
    keep: np.ndarray | None = None


def bin_columns(sizes: list[int], first: bytes | None = None) -> int:
    """Columns (4 or 5) of a sequence's ``.bin`` files, by this rule: a file size that is a
    multiple of 16 bytes and not of 20 means 4 columns, of 20 and not of 16 means 5; when every
    size is a multiple of 80 (both fit), the first file is read as 5 columns and its fifth column
    decides: all whole numbers in [0, 1024) (a ring index) means 5, anything else 4."""
    fits4 = all(s % 16 == 0 for s in sizes)
    fits5 = all(s % 20 == 0 for s in sizes)
    if fits4 != fits5:
        return 4 if fits4 else 5
    if not fits4:
        return 4  # neither fits: the per-file check names the truncated file
    if first is None or not first:
        return 4
    ring = np.frombuffer(first, dtype=np.float32).reshape(-1, 5)[:, 4]
    whole = (
        np.isfinite(ring).all() and (ring == np.round(ring)).all() and ring.min() >= 0 and ring.max() < 1024
    )
    return 5 if whole else 4


def read_points(path: Path, columns: int = 4, intensity_field: str | None = None) -> Points:
    """Decode one scan file by its suffix.

    Args:
        columns: columns of a ``.bin`` file (see :func:`bin_columns`).
        intensity_field: the intensity field's name; default the first of :data:`INTENSITY_NAMES`.

    Raises:
        PointFileFormatError: malformed file, no x/y/z.
        ScanFormatError: inf or far coordinates (:func:`dsnet_core.io.checks.check_points`); points
            with NaN x/y/z are no returns, dropped and recorded in ``Points.keep``.
        IntensityFormatError: an intensity column of an unsupported type.
        MissingExtraError: the format's library is not installed.
    """
    suffix = path.suffix.lower()
    if suffix not in _DECODERS:
        raise PointFileFormatError(path, f"unknown scan suffix {suffix!r}; known: {', '.join(SUFFIXES)}")
    pts = _DECODERS[suffix](path, columns, intensity_field)
    pts.xyz, pts.keep = drop_no_returns(pts.xyz)
    if pts.keep is not None and pts.intensity is not None:
        pts.intensity = pts.intensity[pts.keep]
    check_points(path, pts.xyz)
    if pts.intensity is not None:
        check_column(pts.intensity, path, pts.field or "intensity")
    return pts


def _bin(path: Path, columns: int, _: str | None) -> Points:
    raw = path.read_bytes()
    if len(raw) % (4 * columns):
        raise PointFileFormatError(
            path, f"size {len(raw)} bytes is not a multiple of {4 * columns} (float32 × {columns} columns)"
        )
    arr = np.frombuffer(raw, dtype=np.float32).reshape(-1, columns)
    return Points(arr[:, :3], arr[:, 3], "column 4")


def _plain(arr: np.ndarray, path: Path) -> Points:
    if arr.ndim != 2 or arr.shape[1] not in (3, 4, 5) or arr.dtype.kind != "f":
        raise PointFileFormatError(path, f"expected a float (N, 3|4|5) array, got {arr.dtype} {arr.shape}")
    return Points(arr[:, :3].astype(np.float32), arr[:, 3] if arr.shape[1] > 3 else None, "column 4")


def _named(columns: dict[str, np.ndarray], path: Path, want: str | None) -> Points:
    lower = {k.lower(): k for k in columns}
    missing = [c for c in "xyz" if c not in lower]
    if missing:
        raise PointFileFormatError(
            path, f"no {'/'.join(missing)} field (fields: {', '.join(columns) or 'none'})"
        )
    xyz = np.empty((len(columns[lower["x"]]), 3), dtype=np.float32)
    for i, c in enumerate("xyz"):
        col = np.asarray(columns[lower[c]])
        if col.dtype.kind != "f" or col.ndim != 1:
            raise PointFileFormatError(
                path, f"field {c} has type {col.dtype}{list(col.shape[1:])}, expected a float"
            )
        xyz[:, i] = col
    names = (want.lower(),) if want else INTENSITY_NAMES
    for name in names:
        if name in lower:
            return Points(xyz, np.asarray(columns[lower[name]]), lower[name])
    if want:
        raise PointFileFormatError(path, f"no intensity field {want!r} (fields: {', '.join(columns)})")
    return Points(xyz, None, None)


def _structured(arr: np.ndarray, path: Path, want: str | None) -> Points:
    return _named({n: arr[n] for n in arr.dtype.names}, path, want)


def _npy(path: Path, _: int, want: str | None) -> Points:
    try:
        arr = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise PointFileFormatError(path, f"not a readable .npy array: {exc}") from exc
    return _structured(arr, path, want) if arr.dtype.names else _plain(arr, path)


def _npz(path: Path, _: int, want: str | None) -> Points:
    try:
        with np.load(path, allow_pickle=False) as npz:
            arrays = {k: npz[k] for k in npz.files}
    except (OSError, ValueError) as exc:
        raise PointFileFormatError(path, f"not a readable .npz archive: {exc}") from exc
    for key in ("points", "scan"):
        if key in arrays:
            arr = arrays[key]
            return _structured(arr, path, want) if arr.dtype.names else _plain(arr, path)
    return _named(arrays, path, want)


def _pcd(path: Path, _: int, want: str | None) -> Points:
    arr = read_pcd(path)
    return _structured(arr, path, want)


_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
    "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}  # fmt: skip


def _ply_ascii(path: Path, want: str | None) -> Points | None:
    """Fast path for ASCII PLY whose first element is a vertex of scalar properties (numpy parses
    the rows; plyfile's text reader is ~10× slower); None when the file is anything else."""
    with path.open("rb") as fh:
        if fh.readline().strip() != b"ply" or fh.readline().split()[:2] != [b"format", b"ascii"]:
            return None
        elements: list[str] = []
        count, props = 0, []
        for raw in fh:
            words = raw.decode("ascii", "replace").split()
            if not words or words[0] in ("comment", "obj_info"):
                continue
            if words[0] == "end_header":
                break
            if words[0] == "element" and len(words) == 3:
                elements.append(words[1])
                if elements == ["vertex"]:
                    count = int(words[2])
            elif words[0] == "property" and elements == ["vertex"]:
                if words[1] == "list" or words[1] not in _PLY_TYPES:
                    return None
                props.append((words[-1], _PLY_TYPES[words[1]]))
        else:
            return None
        if not elements or elements[0] != "vertex" or not props:
            return None
        body = fh.read()
    flat, bad = parse_numbers(body, count * len(props))
    if bad is not None or flat.size < count * len(props):
        raise PointFileFormatError(
            path,
            f"ascii body has {flat.size} values before {'a non-number' if bad is not None else 'its end'}, "
            f"header promises {count} × {len(props)}: truncated",
        )
    values = flat.reshape(count, len(props))
    return _named({name: values[:, i].astype(code) for i, (name, code) in enumerate(props)}, path, want)


def _ply(path: Path, _: int, want: str | None) -> Points:
    try:
        fast = _ply_ascii(path, want)
    except (ValueError, UnicodeError):
        fast = None  # let plyfile report what is wrong
    if fast is not None:
        return fast
    try:
        from plyfile import PlyData, PlyParseError
    except ImportError as exc:
        raise MissingExtraError("plyfile", "formats", f"{path}: PLY scans") from exc
    try:
        ply = PlyData.read(str(path))
    except (PlyParseError, ValueError, OSError, EOFError) as exc:
        raise PointFileFormatError(path, f"not a readable PLY file: {' '.join(str(exc).split())}") from exc
    if "vertex" not in ply:
        raise PointFileFormatError(path, "PLY file has no 'vertex' element")
    data = ply["vertex"].data
    return _named({n: data[n] for n in data.dtype.names}, path, want)


def _las(path: Path, _: int, want: str | None) -> Points:
    try:
        import laspy
    except ImportError as exc:
        raise MissingExtraError("laspy", "formats", f"{path}: LAS/LAZ scans") from exc
    try:
        las = laspy.read(path)
    except (laspy.errors.LaspyException, OSError, ValueError) as exc:
        msg = " ".join(str(exc).split())
        if "lazrs" in msg.lower() or "backend" in msg.lower():
            raise MissingExtraError("lazrs", "formats", f"{path}: LAZ scans") from exc
        raise PointFileFormatError(path, f"not a readable LAS/LAZ file: {msg}") from exc
    h = las.header
    scales, offsets = np.asarray(h.scales, np.float64), np.asarray(h.offsets, np.float64)
    if not (np.isfinite(scales).all() and np.isfinite(offsets).all()) or (scales == 0).any():
        raise PointFileFormatError(
            path,
            f"header scale factors {scales.tolist()} and offsets {offsets.tolist()} are degenerate (a scale "
            "of 0 puts every point at the offset; a NaN or inf one nowhere): not a usable LAS header",
        )
    xyz = np.empty((len(las.points), 3), dtype=np.float32)
    for i, (c, scale, offset) in enumerate(zip("XYZ", h.scales, h.offsets, strict=True)):
        xyz[:, i] = np.asarray(las.points[c], dtype=np.float64) * scale + offset
    field = (want or "intensity").lower()
    names = {n.lower(): n for n in las.point_format.dimension_names}
    if field not in names:
        raise PointFileFormatError(path, f"no field {field!r} (fields: {', '.join(names.values())})")
    return Points(xyz, np.asarray(las.points[names[field]]), field)


_DECODERS = {
    ".bin": _bin,
    ".npy": _npy,
    ".npz": _npz,
    ".pcd": _pcd,
    ".ply": _ply,
    ".las": _las,
    ".laz": _las,
}
