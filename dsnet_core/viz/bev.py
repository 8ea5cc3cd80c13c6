"""Bird's-eye-view rasters of a labelled scan, coloured by instance (things) or class (stuff)."""

from __future__ import annotations

import numpy as np

from dsnet_core.labels import LabelMap

BACKGROUND = np.array([24, 26, 31], dtype=np.uint8)


def instance_colour(ids: np.ndarray) -> np.ndarray:
    """A bright, stable colour per instance id: ``(N,) int`` -> ``(N, 3) uint8`` (golden-ratio hues)."""
    hue = (np.asarray(ids, dtype=np.float64) * 0.618033988749895) % 1.0
    h6 = hue * 6.0
    x = 1.0 - np.abs(h6 % 2.0 - 1.0)
    sector = h6.astype(np.int64) % 6
    z = np.zeros_like(hue)
    one = np.ones_like(hue)
    r = np.choose(sector, [one, x, z, z, x, one])
    g = np.choose(sector, [x, one, one, x, z, z])
    b = np.choose(sector, [z, z, x, one, one, x])
    rgb = np.stack([r, g, b], axis=1) * 0.85 + 0.15
    return (rgb * 255).astype(np.uint8)


DIM = 0.45
"""Brightness of the class colour of stuff (and of things without an id) in :func:`label_colours`."""


def class_colours(label_map: LabelMap) -> np.ndarray:
    """The colour of each train id: the map's ``color_map`` of its raw id, else a stable hue.

    Returns:
        ``(num_classes, 3) uint8`` RGB; class 0 (ignored) is grey where the map gives no colour.
    """
    out = instance_colour(np.arange(label_map.num_classes) * 7 + 3)
    out[0] = (128, 128, 128)
    for train, raw in label_map.learning_map_inv.items():
        bgr = label_map.color_map.get(raw)
        if bgr is not None and 0 <= train < label_map.num_classes:
            out[train] = np.asarray(bgr[::-1], dtype=np.uint8)
    return out


def class_point_colours(labels: np.ndarray, label_map: LabelMap) -> np.ndarray:
    """Per point colour by class only (full brightness, :func:`class_colours`), for pictures with a
    class legend: ``(N,) uint32`` raw ``sem | inst << 16`` -> ``(N, 3) uint8`` RGB."""
    sem = (np.asarray(labels, dtype=np.uint32) & 0xFFFF).astype(np.int64)
    train = label_map.lut(1 << 16, fill=0)[sem]
    return class_colours(label_map)[train]


def label_colours(labels: np.ndarray, label_map: LabelMap) -> np.ndarray:
    """Per point colour: thing points with an instance id by instance, the rest by class (dimmed by
    :data:`DIM`).

    Args:
        labels: ``(N,) uint32`` raw ``sem | inst << 16``.
        label_map: gives ``learning_map``, things and ``color_map`` (BGR in the YAML).

    Returns:
        ``(N, 3) uint8`` RGB.
    """
    labels = np.asarray(labels, dtype=np.uint32)
    sem = (labels & 0xFFFF).astype(np.int64)
    inst = (labels >> 16).astype(np.int64)
    lut = np.zeros((1 << 16, 3), dtype=np.uint8)
    for raw, bgr in label_map.color_map.items():
        if 0 <= raw < 1 << 16:
            lut[raw] = (np.asarray(bgr[::-1], dtype=np.float64) * DIM).astype(np.uint8)
    train = label_map.lut(1 << 16, fill=0)
    out = lut[sem]
    thing = np.isin(train[sem], np.asarray(label_map.things)) & (inst > 0)
    out[thing] = instance_colour(inst[thing] * 131 + sem[thing])
    return out


def render_bev(
    xy: np.ndarray,
    colours: np.ndarray,
    extent_m: float = 40.0,
    size: int = 240,
    draw_last: np.ndarray | None = None,
) -> np.ndarray:
    """Rasterise points seen from above, sensor at the centre, x (forward) pointing up.

    Args:
        xy: ``(N, 2) float`` point positions in metres (sensor frame).
        colours: ``(N, 3) uint8`` RGB per point.
        extent_m: half width of the square picture in metres.
        size: picture side in pixels.
        draw_last: optional ``(N,) bool``; these points are drawn on top of the others.

    Returns:
        ``(size, size, 3) uint8`` image.
    """
    img = np.empty((size, size, 3), dtype=np.uint8)
    img[:] = BACKGROUND
    xy = np.asarray(xy, dtype=np.float64)
    scale = size / (2.0 * extent_m)
    row = np.floor((extent_m - xy[:, 0]) * scale).astype(np.int64)
    col = np.floor((extent_m - xy[:, 1]) * scale).astype(np.int64)
    inside = (row >= 0) & (row < size) & (col >= 0) & (col < size)
    order = np.flatnonzero(inside)
    if draw_last is not None:
        order = order[np.argsort(np.asarray(draw_last)[order], kind="stable")]
    # 2×2 pixel dots, drawn point after point (later points cover earlier ones)
    r = np.minimum(row[order][:, None] + np.array([0, 0, 1, 1]), size - 1).ravel()
    c = np.minimum(col[order][:, None] + np.array([0, 1, 0, 1]), size - 1).ravel()
    img[r, c] = np.repeat(colours[order], 4, axis=0)
    c = size // 2
    img[c - 1 : c + 2, c - 1 : c + 2] = 255  # the sensor
    return img
