"""PCL's ``.pcd`` point-cloud files (v0.5–v0.7): ``DATA ascii``, ``binary`` and ``binary_compressed``.

The header names the fields, their byte sizes, types (``F`` float, ``U`` unsigned, ``I`` signed)
and counts; ``binary`` stores points row after row, ``binary_compressed`` stores an LZF block
(two uint32 sizes, compressed then uncompressed) of the fields one after the other. LZF comes
from ``python-neo-lzf`` (extra ``formats``).

The header and the body must agree: ``POINTS`` equals ``WIDTH × HEIGHT`` (when the header has
both), and the body holds exactly ``POINTS`` points (``binary``: that many bytes; ``ascii``: that
many rows of values; ``binary_compressed``: a block that unpacks to that many bytes, and nothing
after it). A disagreement is an error naming both numbers: which of them is right cannot be told,
and reading either silently gives labels of the wrong length.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dsnet_core.errors import MissingExtraError, PointFileFormatError
from dsnet_core.io.asciinum import parse_numbers

_TYPES = {("F", 4): "f4", ("F", 8): "f8", ("F", 2): "f2"}
_TYPES.update({("U", n): f"u{n}" for n in (1, 2, 4, 8)})
_TYPES.update({("I", n): f"i{n}" for n in (1, 2, 4, 8)})
_KEYS = ("VERSION", "FIELDS", "SIZE", "TYPE", "COUNT", "WIDTH", "HEIGHT", "VIEWPOINT", "POINTS", "DATA")
ENCODINGS = ("ascii", "binary", "binary_compressed")


def read_pcd(path: str | Path) -> np.ndarray:
    """Read a ``.pcd`` file as a structured array ``(N,)``, one named field per PCD field (a field
    with COUNT > 1 is a sub-array; PCL's padding fields ``_`` are dropped).

    Raises:
        PointFileFormatError: a header line missing or malformed, an unknown ``DATA`` encoding
            or field type, ``POINTS`` ≠ ``WIDTH × HEIGHT``, or a body that holds another number
            of points than ``POINTS`` (shorter: truncated; longer: the header undercounts).
    """
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise PointFileFormatError(path, f"cannot read: {exc.strerror or exc}") from exc
    header, body = _split_header(raw, path)
    dtype, n, encoding = _layout(header, path)
    if encoding == "ascii":
        data = _ascii(body, dtype, n, path)
    elif encoding == "binary":
        data = _binary(body, dtype, n, path)
    else:
        data = _compressed(body, dtype, n, path)
    keep = [name for name in dtype.names if not name.startswith("_")]
    return data[keep] if len(keep) < len(dtype.names) else data


def _split_header(raw: bytes, path: Path) -> tuple[dict[str, list[str]], bytes]:
    header: dict[str, list[str]] = {}
    pos = 0
    while "DATA" not in header:
        end = raw.find(b"\n", pos)
        if end < 0:
            raise PointFileFormatError(path, "header ends before its DATA line (not a PCD file?)")
        line = raw[pos:end].decode("ascii", "replace").strip()
        pos = end + 1
        if not line or line.startswith("#"):
            continue
        key, *values = line.split()
        if key.upper() not in _KEYS:
            raise PointFileFormatError(path, f"unknown PCD header line {line[:60]!r}")
        header[key.upper()] = values
    return header, raw[pos:]


def _layout(header: dict[str, list[str]], path: Path) -> tuple[np.dtype, int, str]:
    encoding = header["DATA"][0].lower() if header["DATA"] else ""
    if encoding not in ENCODINGS:
        raise PointFileFormatError(path, f"unknown DATA {encoding or '(empty)'!r}; PCD has {ENCODINGS}")
    for key in ("FIELDS", "SIZE", "TYPE"):
        if key not in header:
            raise PointFileFormatError(path, f"header has no {key} line")
    fields, sizes, types = header["FIELDS"], header["SIZE"], header["TYPE"]
    counts = header.get("COUNT", ["1"] * len(fields))
    if not (len(fields) == len(sizes) == len(types) == len(counts)):
        raise PointFileFormatError(path, "FIELDS, SIZE, TYPE and COUNT have different lengths")
    n = _point_count(header, path)
    try:
        sizes_i, counts_i = [int(s) for s in sizes], [int(c) for c in counts]
    except ValueError as exc:
        raise PointFileFormatError(path, f"header has a non-integer size or count: {exc}") from exc
    spec = []
    for i, (name, size, typ, count) in enumerate(zip(fields, sizes_i, types, counts_i, strict=True)):
        code = _TYPES.get((typ.upper(), size))
        if code is None:
            raise PointFileFormatError(path, f"field {name!r} has unknown TYPE {typ} with SIZE {size}")
        name = name if name != "_" else f"_{i}"
        spec.append((name, "<" + code, (count,)) if count > 1 else (name, "<" + code))
    return np.dtype(spec), n, encoding


def _header_int(header: dict[str, list[str]], key: str, path: Path) -> int | None:
    if key not in header:
        return None
    values = header[key]
    try:
        value = int(values[0])
    except (ValueError, IndexError):
        raise PointFileFormatError(path, f"header line {key} {' '.join(values)!r} is not a count") from None
    if value < 0 or len(values) != 1:
        raise PointFileFormatError(path, f"header line {key} {' '.join(values)!r} is not a count")
    return value


def _point_count(header: dict[str, list[str]], path: Path) -> int:
    """``POINTS``, checked against ``WIDTH × HEIGHT`` (``WIDTH × HEIGHT`` when there is no ``POINTS``)."""
    points = _header_int(header, "POINTS", path)
    width = _header_int(header, "WIDTH", path)
    height = _header_int(header, "HEIGHT", path)
    if width is None:
        if points is None:
            raise PointFileFormatError(path, "header has neither POINTS nor WIDTH")
        return points
    grid = width * (1 if height is None else height)
    if points is not None and points != grid:
        raise PointFileFormatError(
            path,
            f"header says POINTS {points} but WIDTH × HEIGHT = {width} × {1 if height is None else height} "
            f"= {grid}: the header disagrees with itself",
        )
    return grid


def _binary(body: bytes, dtype: np.dtype, n: int, path: Path) -> np.ndarray:
    need = n * dtype.itemsize
    if len(body) < need:
        raise PointFileFormatError(
            path,
            f"binary body has {len(body)} bytes, the header promises "
            f"{n} points × {dtype.itemsize} = {need}: truncated",
        )
    if len(body) > need:
        held = (
            f"holds {len(body) // dtype.itemsize} points ({len(body)} bytes)"
            if len(body) % dtype.itemsize == 0
            else f"has {len(body)} bytes"
        )
        raise PointFileFormatError(
            path,
            f"binary body {held}, the header says POINTS {n} ({n} × {dtype.itemsize} = {need} bytes): "
            "the header and the body disagree",
        )
    return np.frombuffer(body, dtype=dtype, count=n)


def _ascii(body: bytes, dtype: np.dtype, n: int, path: Path) -> np.ndarray:
    cols = sum(int(np.prod(dtype[name].shape)) if dtype[name].shape else 1 for name in dtype.names)
    flat, bad = parse_numbers(body, n * cols + 1)  # one more: a longer body is an error too
    if bad is not None:
        token = body[bad : bad + 20].split()[0].decode("ascii", "replace")
        raise PointFileFormatError(path, f"ascii body is not numeric at byte {bad}: {token!r}")
    if flat.size < n * cols:
        raise PointFileFormatError(
            path, f"ascii body has {flat.size} values, the header promises {n} points × {cols}: truncated"
        )
    if flat.size > n * cols:
        rows = sum(1 for line in body.splitlines() if line.strip())
        values = len(body.split())
        held = f"{rows} rows" if values == rows * cols else f"{values} values in {rows} rows"
        raise PointFileFormatError(
            path,
            f"ascii body holds {held}, the header says POINTS {n} (of {cols} values each): "
            "the header and the body disagree",
        )
    values = flat[: n * cols].reshape(n, cols)
    out = np.empty(n, dtype=dtype)
    col = 0
    for name in dtype.names:
        width = int(np.prod(dtype[name].shape)) if dtype[name].shape else 1
        part = values[:, col : col + width]
        out[name] = part.reshape(out[name].shape) if width > 1 else part[:, 0]
        col += width
    return out


def _compressed(body: bytes, dtype: np.dtype, n: int, path: Path) -> np.ndarray:
    try:
        import lzf
    except ImportError as exc:
        raise MissingExtraError("python-neo-lzf", "formats", f"{path}: binary_compressed PCD") from exc
    if len(body) < 8:
        raise PointFileFormatError(path, "binary_compressed body is shorter than its two size words")
    packed, unpacked = np.frombuffer(body[:8], dtype="<u4").tolist()
    need = n * dtype.itemsize
    if unpacked != need:
        held = f" ({unpacked // dtype.itemsize} points)" if unpacked % dtype.itemsize == 0 else ""
        raise PointFileFormatError(
            path,
            f"compressed block unpacks to {unpacked} bytes{held}, the header says POINTS {n} "
            f"({n} × {dtype.itemsize} = {need} bytes): the header and the body disagree",
        )
    if len(body) - 8 < packed:
        raise PointFileFormatError(
            path, f"compressed block has {len(body) - 8} of its {packed} bytes: truncated"
        )
    if len(body) - 8 > packed:
        raise PointFileFormatError(
            path, f"body has {len(body) - 8 - packed} bytes after its compressed block of {packed} bytes"
        )
    try:
        data = lzf.decompress(body[8 : 8 + packed], unpacked) if unpacked else b""
    except ValueError:
        data = None
    if data is None:
        raise PointFileFormatError(
            path, f"compressed block does not decompress to its stated {unpacked} bytes (corrupt LZF data)"
        )
    if len(data) != unpacked:
        raise PointFileFormatError(
            path, f"compressed block decompresses to {len(data)} bytes, its size word says {unpacked}"
        )
    out = np.empty(n, dtype=dtype)
    pos = 0
    for name in dtype.names:  # fields one after another, each n × its size
        field = dtype[name]
        size = n * field.itemsize
        out[name] = np.frombuffer(
            data, dtype=field.base, count=n * max(1, int(np.prod(field.shape))), offset=pos
        ).reshape(out[name].shape)
        pos += size
    return out
