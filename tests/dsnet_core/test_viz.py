"""PNG encoder/decoder round trips (every row filter) and bird's-eye-view rasters."""

from __future__ import annotations

import struct
import zlib

import numpy as np
import pytest

from dsnet_core.labels import load_label_map
from dsnet_core.viz.bev import label_colours, render_bev
from dsnet_core.viz.png import SIGNATURE, decode_png, encode_png


def _paeth(a: int, b: int, c: int) -> int:
    p = a + b - c
    pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
    return a if pa <= pb and pa <= pc else (b if pb <= pc else c)


def _filtered_png(img: np.ndarray) -> bytes:
    """A reference encoder (pure Python) cycling through filters 0..4 row by row (RGBA)."""
    h, w, ch = img.shape
    rows, prev = [], [0] * (w * ch)
    for y in range(h):
        cur = [int(v) for v in img[y].reshape(-1)]
        f = y % 5
        line = [f]
        for x, v in enumerate(cur):
            a = cur[x - ch] if x >= ch else 0
            b, c = prev[x], prev[x - ch] if x >= ch else 0
            pred = [0, a, b, (a + b) // 2, _paeth(a, b, c)][f]
            line.append((v - pred) & 0xFF)
        rows.append(bytes(line))
        prev = cur

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    head = struct.pack(">IIBBBBB", w, h, 8, 6, 0, 0, 0)
    return (
        SIGNATURE + chunk(b"IHDR", head) + chunk(b"IDAT", zlib.compress(b"".join(rows))) + chunk(b"IEND", b"")
    )


def test_png_round_trip_and_all_filters():
    rng = np.random.default_rng(0)
    img = rng.integers(0, 256, size=(17, 23, 3), dtype=np.uint8)
    assert np.array_equal(decode_png(encode_png(img)), img)
    rgba = rng.integers(0, 256, size=(11, 9, 4), dtype=np.uint8)
    assert np.array_equal(decode_png(_filtered_png(rgba)), rgba)
    with pytest.raises(ValueError, match=r"\(H, W, 3\) uint8"):
        encode_png(img.astype(np.float32))
    with pytest.raises(ValueError, match="not a PNG"):
        decode_png(b"GIF89a")


def test_bev_places_points_and_colours_instances():
    lm = load_label_map("semantic-kitti")
    xy = np.array([[10.0, 0.0], [-10.0, 0.0], [0.0, 10.0], [0.0, 0.0], [100.0, 0.0]])
    labels = np.array([10 | 1 << 16, 10 | 2 << 16, 40, 40, 40], dtype=np.uint32)  # 2 cars, road
    colours = label_colours(labels, lm)
    assert not np.array_equal(colours[0], colours[1])  # two instances, two colours
    road = np.array(lm.color_map[40][::-1]) * 0.45
    assert np.array_equal(colours[2], road.astype(np.uint8))
    img = render_bev(xy, colours, extent_m=20.0, size=40)
    assert img.shape == (40, 40, 3)
    assert np.array_equal(img[10, 20], colours[0])  # 10 m forward -> up
    assert np.array_equal(img[30, 20], colours[1])  # 10 m behind -> down
    assert np.array_equal(img[20, 10], colours[2])  # 10 m left (+y) -> left


def test_class_colours_follow_the_label_map_and_fill_the_gaps():
    from dsnet_core.labels import class_map_of, label_map_from_class_map
    from dsnet_core.viz.bev import DIM, class_colours, class_point_colours

    lm = load_label_map("semantic-kitti")
    colours = class_colours(lm)
    assert colours.shape == (lm.num_classes, 3) and colours.dtype == np.uint8
    for train, raw in lm.learning_map_inv.items():  # the YAML's BGR as RGB
        assert colours[train].tolist() == list(lm.color_map[raw][::-1])
    labels = np.array([10 | 3 << 16, 40, 30 | 7 << 16], dtype=np.uint32)  # car (instance 3), road, person
    by_class = class_point_colours(labels, lm)  # instances do not change a class picture's colour
    assert by_class.tolist() == [colours[1].tolist(), colours[9].tolist(), colours[6].tolist()]
    assert label_colours(labels[1:2], lm)[0].tolist() == (colours[9] * DIM).astype(np.uint8).tolist()
    bare = label_map_from_class_map({**class_map_of(lm), "name": "custom"})  # a map without colours
    got = class_colours(bare)
    assert got[0].tolist() == [128, 128, 128]
    assert len({tuple(c) for c in got[1:].tolist()}) == lm.num_classes - 1  # distinct hues
