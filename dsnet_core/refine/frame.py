"""One frame as refinement reads it, its labels' encoding, and the weight of each point's vote.

Votes are integers, so that sums over any set of frames are exact whatever order they are added
in: a point's vote for class ``c`` is ``q_c · w_range · w_conf`` with ``q_c`` its probability
quantised to 0..255 (255 for its one hard class where there are no probabilities), ``w_range``
its range weight and ``w_conf`` its instance's confidence, both quantised to 1..255. One point
of full weight therefore casts :data:`FULL_VOTE`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dsnet_core.labels import LabelMap

Q = 255
"""Quantisation of probabilities and weights: 1.0 is 255."""

FULL_VOTE = Q * Q * Q
"""The vote of one point of probability, range weight and confidence 1."""


@dataclass(frozen=True)
class FrameInput:
    """One frame's labels with what refinement needs beside them.

    Attributes:
        index: the frame's index in the sequence.
        time: seconds (any origin, the same for the whole sequence).
        pose: ``(4, 4) float64`` sensor -> world, or None (no poses: nothing in the world frame).
        xyz: ``(N, 3) float32`` points in the sensor frame, metres, in the labels' order.
        sem: ``(N,) int64`` train ids.
        inst: ``(N,) int64`` sequence-wide tracks, 0 = none: their keys ``id | generation << 16``
            (:mod:`dsnet_core.temporal.ids`), the label's ids unless the temporal stage reused ids.
        probs: ``(N, C) uint8`` class probabilities quantised as ``p = q / 255``, or None (hard
            labels only).
        intensity: ``(N,) float32`` remission (0-1) for the ground segmentation, or None.
    """

    index: int
    time: float
    pose: np.ndarray | None
    xyz: np.ndarray
    sem: np.ndarray
    inst: np.ndarray
    probs: np.ndarray | None = None
    intensity: np.ndarray | None = None

    def __post_init__(self) -> None:
        n = self.xyz.shape[0]
        if self.xyz.shape != (n, 3) or self.sem.shape != (n,) or self.inst.shape != (n,):
            raise ValueError(
                f"frame {self.index}: xyz {self.xyz.shape}, sem {self.sem.shape} and inst "
                f"{self.inst.shape} must describe the same {n} points"
            )
        if self.probs is not None and (self.probs.ndim != 2 or self.probs.shape[0] != n):
            raise ValueError(f"frame {self.index}: probs {self.probs.shape} do not match {n} points")
        if self.pose is not None and np.shape(self.pose) != (4, 4):
            raise ValueError(f"frame {self.index}: pose must be 4x4, got {np.shape(self.pose)}")

    @property
    def n_points(self) -> int:
        return int(self.xyz.shape[0])

    def world(self) -> np.ndarray:
        """``(N, 3) float64`` points in the world frame (the sensor frame without a pose).

        Element-wise products and sums (no BLAS), so the result does not depend on the CPU."""
        p = self.xyz.astype(np.float64)
        if self.pose is None:
            return p
        m = np.asarray(self.pose, np.float64)
        out = np.empty_like(p)
        for r in range(3):
            out[:, r] = p[:, 0] * m[r, 0] + p[:, 1] * m[r, 1] + p[:, 2] * m[r, 2] + m[r, 3]
        return out

    def ranges(self) -> np.ndarray:
        """``(N,) float64`` distance of each point from the sensor, metres."""
        p = self.xyz.astype(np.float64)
        return np.sqrt(p[:, 0] * p[:, 0] + p[:, 1] * p[:, 1] + p[:, 2] * p[:, 2])


def decode_labels(label: np.ndarray, label_map: LabelMap) -> tuple[np.ndarray, np.ndarray]:
    """``raw semantic | id << 16`` ``(N,) uint32`` -> train ids and ids, both ``(N,) int64``.

    Raw ids the map does not know become train id 0 (ignored)."""
    label = np.asarray(label, np.uint32)
    lut = label_map.lut(1 << 16, fill=0)
    return lut[label & 0xFFFF].astype(np.int64), (label >> 16).astype(np.int64)


def encode_labels(sem: np.ndarray, inst: np.ndarray, label_map: LabelMap) -> np.ndarray:
    """Train ids and ids (or track keys: their lower 16 bits are the id) ``(N,)`` -> ``raw semantic |
    id << 16`` ``(N,) uint32``."""
    raw = label_map.inv_lut()[np.asarray(sem, np.int64)]
    return raw | ((np.asarray(inst, np.int64) & 0xFFFF).astype(np.uint32) << np.uint32(16))


def quantise(x: np.ndarray) -> np.ndarray:
    """Shares in [0, 1] ``(N,)`` -> ``(N,) int64`` weights 1..255 (a weight never reaches 0)."""
    return np.clip(np.rint(np.asarray(x, np.float64) * Q), 1, Q).astype(np.int64)


def range_weights(frame: FrameInput, range_ref: float | None) -> np.ndarray:
    """``(N,) int64`` 1..255: full weight within ``range_ref`` metres, ``range_ref / range`` beyond."""
    if range_ref is None:
        return np.full(frame.n_points, Q, np.int64)
    r = frame.ranges()
    return quantise(np.minimum(1.0, range_ref / np.maximum(r, 1e-6)))


@dataclass(frozen=True)
class Confidence:
    """Instance confidences of the tracks, as vote weights (hard labels are one-hot votes weighted
    by them; with probabilities every point weighs 255: the probabilities carry the confidence).

    Attributes:
        ids: ``(K,) int64`` track ids, sorted.
        weight: ``(K,) int64`` their weights 1..255.
    """

    ids: np.ndarray
    weight: np.ndarray

    @classmethod
    def from_mapping(cls, confidence: dict[int, float] | None) -> Confidence:
        """From ``{id: confidence in [0, 1]}`` (None or empty: every track weighs 255)."""
        items = sorted((confidence or {}).items())
        ids = np.asarray([i for i, _ in items], np.int64)
        return cls(ids, quantise(np.asarray([c for _, c in items], np.float64)))

    def point_weights(self, inst: np.ndarray, use: bool = True) -> np.ndarray:
        """``(N,) int64``: each point's instance weight (255 for points without an instance, for
        ids without a confidence, and everywhere when ``use`` is False)."""
        out = np.full(inst.shape, Q, np.int64)
        if not use or self.ids.size == 0:
            return out
        pos = np.clip(np.searchsorted(self.ids, inst), 0, self.ids.size - 1)
        hit = (inst > 0) & (self.ids[pos] == inst)
        out[hit] = self.weight[pos[hit]]
        return out
