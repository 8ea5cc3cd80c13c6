"""PCL's ``.pcd`` point-cloud files (v0.5–v0.7): ``DATA ascii``, ``binary`` and ``binary_compressed``.

The header names the fields, their byte sizes, types (``F`` float, ``U`` unsigned, ``I`` signed)
and counts; ``binary`` stores points row after row, ``binary_compressed`` stores an LZF block
(two uint32 sizes, compressed then uncompressed) of the fields one after the other. LZF comes
from ``python-neo-lzf`` (extra ``formats``).
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
            or field type, or a body shorter than the header promises.
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
        need = n * dtype.itemsize
        if len(body) < need:
            raise PointFileFormatError(
                path,
                f"binary body has {len(body)} bytes, the header promises "
                f"{n} points × {dtype.itemsize} = {need}: truncated",
            )
        data = np.frombuffer(body, dtype=dtype, count=n)
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
    try:
        width = int(header.get("WIDTH", ["0"])[0])
        height = int(header.get("HEIGHT", ["1"])[0])
        n = int(header["POINTS"][0]) if "POINTS" in header else width * height
        sizes_i, counts_i = [int(s) for s in sizes], [int(c) for c in counts]
    except (ValueError, IndexError) as exc:
        raise PointFileFormatError(
            path, f"header has a non-integer size, count or point number: {exc}"
        ) from exc
    spec = []
    for i, (name, size, typ, count) in enumerate(zip(fields, sizes_i, types, counts_i, strict=True)):
        code = _TYPES.get((typ.upper(), size))
        if code is None:
            raise PointFileFormatError(path, f"field {name!r} has unknown TYPE {typ} with SIZE {size}")
        name = name if name != "_" else f"_{i}"
        spec.append((name, "<" + code, (count,)) if count > 1 else (name, "<" + code))
    return np.dtype(spec), n, encoding


def _ascii(body: bytes, dtype: np.dtype, n: int, path: Path) -> np.ndarray:
    cols = sum(int(np.prod(dtype[name].shape)) if dtype[name].shape else 1 for name in dtype.names)
    flat, bad = parse_numbers(body, n * cols)
    if bad is not None:
        token = body[bad : bad + 20].split()[0].decode("ascii", "replace")
        raise PointFileFormatError(path, f"ascii body is not numeric at byte {bad}: {token!r}")
    if flat.size < n * cols:
        raise PointFileFormatError(
            path, f"ascii body has {flat.size} values, the header promises {n} points × {cols}: truncated"
        )
    values = flat.reshape(n, cols)
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
        raise PointFileFormatError(
            path, f"compressed block unpacks to {unpacked} bytes, {n} points need {need}"
        )
    if len(body) - 8 < packed:
        raise PointFileFormatError(
            path, f"compressed block has {len(body) - 8} of its {packed} bytes: truncated"
        )
    try:
        data = lzf.decompress(body[8 : 8 + packed], unpacked) if unpacked else b""
    except ValueError:
        data = None
    if data is None or len(data) != unpacked:
        raise PointFileFormatError(path, "compressed block does not decompress (corrupt LZF data)")
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
