"""The optional ground prior: a training-free ground segmentation of each scan, and the correction
of low-confidence points whose ground / non-ground group disagrees with it.

The segmenter is anything with :class:`GroundSegmenter`'s call; :class:`Patchwork` wraps
Patchwork++ (pip package ``pypatchworkpp``, BSD-2), an optional extra imported only when built.
"""

from __future__ import annotations

import contextlib
import os
from typing import Protocol

import numpy as np

from dsnet_core.errors import MissingExtraError
from dsnet_core.refine.classes import ClassSets

GROUND, NON_GROUND, UNKNOWN = 1, 0, -1


class GroundSegmenter(Protocol):
    """Labels one scan's points as ground or not."""

    def __call__(self, xyz: np.ndarray, intensity: np.ndarray | None) -> np.ndarray:
        """``(N, 3)`` sensor-frame points (metres) and remission -> ``(N,) int8``: :data:`GROUND`,
        :data:`NON_GROUND` or :data:`UNKNOWN` (points the segmenter did not judge)."""
        ...


@contextlib.contextmanager
def _quiet_stdout():
    """Silence the C++ library's prints to file descriptor 1 (it announces every initialisation)."""
    fd = os.dup(1)
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 1)
            yield
    finally:
        os.dup2(fd, 1)
        os.close(fd)


class Patchwork:
    """Patchwork++ ground segmentation (Lee et al., RA-L 2022) through ``pypatchworkpp``.

    Args:
        sensor_height: the sensor's height above the ground, metres.

    Raises:
        MissingExtraError: ``pypatchworkpp`` is not installed (the message names the pip install).
    """

    def __init__(self, sensor_height: float = 1.73) -> None:
        try:
            import pypatchworkpp
        except ImportError:
            raise MissingExtraError("pypatchworkpp", "ground", "the ground prior (Patchwork++)") from None
        params = pypatchworkpp.Parameters()
        params.sensor_height = float(sensor_height)
        params.verbose = False
        with _quiet_stdout():
            self._pw = pypatchworkpp.patchworkpp(params)

    def __call__(self, xyz: np.ndarray, intensity: np.ndarray | None) -> np.ndarray:
        n = xyz.shape[0]
        out = np.full(n, UNKNOWN, np.int8)
        if n == 0:
            return out
        pts = np.zeros((n, 4), np.float64)
        pts[:, :3] = xyz
        if intensity is not None:
            pts[:, 3] = intensity
        self._pw.estimateGround(pts)
        out[np.asarray(self._pw.getGroundIndices(), np.int64)] = GROUND
        out[np.asarray(self._pw.getNongroundIndices(), np.int64)] = NON_GROUND
        return out


def ground_correction(
    sem: np.ndarray,
    inst: np.ndarray,
    probs: np.ndarray,
    ground: np.ndarray,
    sets: ClassSets,
    max_confidence: float,
    frozen: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Move low-confidence points whose group disagrees with the ground segmentation to the most
    probable class of the other group.

    Only points without an instance are touched (a track's class is its track's), and they only
    receive stuff classes (refinement never makes a thing point without an instance).

    Args:
        sem: ``(N,) int64`` current classes. inst: ``(N,) int64`` current ids.
        probs: ``(N, C) uint8`` quantised probabilities.
        ground: ``(N,) int8`` the segmenter's verdict.
        sets: the class sets (``sets.ground`` must not be empty).
        max_confidence: points whose probability of ``sem`` is below this may change.
        frozen: ``(N,) bool`` points not to touch (e.g. set by the static vote).

    Returns:
        The corrected classes ``(N,) int64`` and the ``(N,) bool`` mask of changed points.
    """
    is_ground = sets.ground[sem]
    p_own = probs[np.arange(sem.size), sem].astype(np.float64) / 255.0
    candidate = (inst == 0) & ~sets.ignore[sem] & (ground != UNKNOWN) & (p_own < max_confidence)
    candidate &= is_ground != (ground == GROUND)
    if frozen is not None:
        candidate &= ~frozen
    to_ground = candidate & (ground == GROUND)
    to_other = candidate & (ground == NON_GROUND)
    out = sem.copy()
    other = sets.stuff & ~sets.ground
    for mask, allowed in ((to_ground, sets.ground), (to_other, other)):
        if mask.any() and allowed.any():
            p = np.where(allowed[None, :], probs[mask].astype(np.int64), -1)
            out[mask] = np.argmax(p, axis=1)
    changed = out != sem
    return out, changed
