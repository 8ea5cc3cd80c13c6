"""PNG encoding and decoding for report pictures, through Pillow.

Thin wrappers that fix the array contract: ``(H, W, 3) uint8`` in, ``(H, W, C) uint8`` out.
"""

from __future__ import annotations

import io

import numpy as np
from PIL import Image, UnidentifiedImageError

SIGNATURE = b"\x89PNG\r\n\x1a\n"


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
    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(img), mode="RGB").save(buf, format="PNG", compress_level=level)
    return buf.getvalue()


def decode_png(data: bytes) -> np.ndarray:
    """Decode an 8-bit grey, grey+alpha, RGB or RGBA PNG to ``(H, W, C) uint8`` (C = 1, 2, 3, 4).

    Raises:
        ValueError: not a PNG, or a mode other than those (palettes, 16-bit samples).
    """
    if not data.startswith(SIGNATURE):
        raise ValueError("not a PNG file")
    try:
        img = Image.open(io.BytesIO(data))
        img.load()
    except (UnidentifiedImageError, OSError) as exc:
        raise ValueError(f"cannot decode PNG: {exc}") from exc
    channels = {"L": 1, "LA": 2, "RGB": 3, "RGBA": 4}.get(img.mode)
    if channels is None:
        raise ValueError(f"unsupported PNG mode {img.mode}")
    return np.asarray(img, dtype=np.uint8).reshape(img.height, img.width, channels)
