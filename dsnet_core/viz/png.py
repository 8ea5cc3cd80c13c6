"""A minimal PNG encoder (8-bit RGB, zlib, no filters): enough for report thumbnails."""

from __future__ import annotations

import struct
import zlib

import numpy as np

SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _chunk(kind: bytes, data: bytes) -> bytes:
    return (
        struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)
    )


def encode_png(rgb: np.ndarray, level: int = 6) -> bytes:
    """Encode an image as PNG bytes.

    Args:
        rgb: ``(H, W, 3) uint8`` image, rows top to bottom.
        level: zlib compression level 0..9.

    Returns:
        The PNG file's bytes.
    """
    img = np.asarray(rgb)
    if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8:
        raise ValueError(f"encode_png needs an (H, W, 3) uint8 array, got {img.shape} {img.dtype}")
    h, w = img.shape[:2]
    raw = np.zeros((h, 1 + 3 * w), dtype=np.uint8)  # filter byte 0 (None) per row
    raw[:, 1:] = img.reshape(h, 3 * w)
    header = struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0)
    return (
        SIGNATURE
        + _chunk(b"IHDR", header)
        + _chunk(b"IDAT", zlib.compress(raw.tobytes(), level))
        + _chunk(b"IEND", b"")
    )


def decode_png(data: bytes) -> np.ndarray:
    """Decode an 8-bit, non-interlaced grey/RGB/RGBA PNG (any row filter) to ``(H, W, C) uint8``.

    Enough to read back our own pictures and a browser's screenshots; palettes, 16-bit samples
    and interlacing raise ``ValueError``.
    """
    if not data.startswith(SIGNATURE):
        raise ValueError("not a PNG file")
    pos, idat, w, h, channels = len(SIGNATURE), [], 0, 0, 0
    while pos < len(data):
        (n,) = struct.unpack(">I", data[pos : pos + 4])
        kind, body = data[pos + 4 : pos + 8], data[pos + 8 : pos + 8 + n]
        if kind == b"IHDR":
            w, h, depth, colour, _, _, interlace = struct.unpack(">IIBBBBB", body[:13])
            channels = {0: 1, 2: 3, 4: 2, 6: 4}.get(colour, 0)
            if depth != 8 or not channels or interlace:
                raise ValueError(f"unsupported PNG: depth {depth}, colour {colour}, interlace {interlace}")
        elif kind == b"IDAT":
            idat.append(body)
        elif kind == b"IEND":
            break
        pos += 12 + n
    raw = np.frombuffer(zlib.decompress(b"".join(idat)), dtype=np.uint8).reshape(h, 1 + channels * w)
    out = np.empty((h, channels * w), dtype=np.uint8)
    _unfilter(raw, out, channels)
    return out.reshape(h, w, channels)


def _unfilter(raw: np.ndarray, out: np.ndarray, bpp: int) -> None:
    """Undo the per-row filters (None, Sub, Up, Average, Paeth) of ``raw`` into ``out``."""
    from numba import njit

    global _unfilter_jit
    if _unfilter_jit is None:
        _unfilter_jit = njit(cache=False, nogil=True)(_unfilter_py)
    _unfilter_jit(raw, out, bpp)


_unfilter_jit = None


def _unfilter_py(raw, out, bpp):  # pragma: no cover - compiled by numba
    h, n = out.shape
    prev = np.zeros(n, dtype=np.int32)
    for y in range(h):
        f = raw[y, 0]
        for x in range(n):
            v = np.int32(raw[y, x + 1])
            a = np.int32(out[y, x - bpp]) if x >= bpp else np.int32(0)
            b = prev[x]
            c = prev[x - bpp] if x >= bpp else np.int32(0)
            if f == 1:
                v += a
            elif f == 2:
                v += b
            elif f == 3:
                v += (a + b) // 2
            elif f == 4:
                p = a + b - c
                pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
                v += a if (pa <= pb and pa <= pc) else (b if pb <= pc else c)
            elif f != 0:
                raise ValueError("bad PNG filter type")
            out[y, x] = np.uint8(v & 0xFF)
        for x in range(n):
            prev[x] = out[y, x]
