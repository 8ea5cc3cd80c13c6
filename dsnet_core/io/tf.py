"""A transform tree from ``/tf`` and ``/tf_static`` (tf2's model, without ROS).

Each edge maps a child frame into its parent (``p_parent = T @ p_child``). Static edges hold one
transform; dynamic edges a time series, interpolated (translation linearly, rotation by slerp)
at the asked time, and held at its end sample up to ``tolerance`` seconds outside it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from dsnet_core.io.geometry import pose_matrix, sample_trajectory


@dataclass
class _Edge:
    parent: str
    times: list[float] = field(default_factory=list)
    translations: list[tuple[float, float, float]] = field(default_factory=list)
    quats: list[tuple[float, float, float, float]] = field(default_factory=list)  # w, x, y, z
    static: bool = False
    _arrays: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        if self._arrays is None:
            t = np.asarray(self.times, dtype=np.float64)
            order = np.argsort(t, kind="stable")
            self._arrays = (t[order], np.asarray(self.translations)[order], np.asarray(self.quats)[order])
        return self._arrays


class TfTree:
    """Transforms between frames at a time.

    Args:
        tolerance: seconds a dynamic edge may be held past either end of its samples.
    """

    def __init__(self, tolerance: float = 0.05) -> None:
        self.tolerance = tolerance
        self._edges: dict[str, _Edge] = {}

    def add(
        self,
        parent: str,
        child: str,
        t: float,
        translation: tuple[float, float, float],
        q_wxyz: tuple[float, float, float, float],
        static: bool = False,
    ) -> None:
        """Record ``parent ← child`` at time ``t`` (seconds); a static edge keeps its latest value."""
        parent, child = parent.lstrip("/"), child.lstrip("/")
        edge = self._edges.get(child)
        if edge is None or edge.parent != parent or static != edge.static:
            edge = self._edges[child] = _Edge(parent, static=static)
        if static:
            edge.times, edge.translations, edge.quats = [t], [translation], [q_wxyz]
        else:
            edge.times.append(t)
            edge.translations.append(translation)
            edge.quats.append(q_wxyz)
        edge._arrays = None

    def frames(self) -> set[str]:
        return set(self._edges) | {e.parent for e in self._edges.values()}

    def connected(self, a: str, b: str) -> bool:
        a, b = a.lstrip("/"), b.lstrip("/")
        return self._chain(a)[-1] == self._chain(b)[-1]

    def lookup(self, target: str, source: str, t: float) -> np.ndarray | None:
        """float64 ``(4, 4)`` mapping ``source`` coordinates into ``target`` at time ``t``, or None
        when the frames are not connected or a dynamic edge on the path has no sample near ``t``."""
        target, source = target.lstrip("/"), source.lstrip("/")
        up_s, up_t = self._chain(source), self._chain(target)
        common = next((f for f in up_s if f in set(up_t)), None)
        if common is None:
            return None
        to_common_s = self._compose(up_s[: up_s.index(common)], t)
        to_common_t = self._compose(up_t[: up_t.index(common)], t)
        if to_common_s is None or to_common_t is None:
            return None
        return np.linalg.inv(to_common_t) @ to_common_s

    def _chain(self, frame: str) -> list[str]:
        """``frame`` and its ancestors up to the root."""
        chain = [frame]
        while chain[-1] in self._edges and len(chain) <= len(self._edges):
            chain.append(self._edges[chain[-1]].parent)
        return chain

    def _compose(self, frames: list[str], t: float) -> np.ndarray | None:
        """Transform from the first of ``frames`` into the parent of the last."""
        out = np.eye(4)
        for child in frames:
            edge = self._edges[child]
            times, trans, quats = edge.arrays()
            if edge.static:
                m = pose_matrix(trans[-1], quats[-1])
            else:
                m = sample_trajectory(times, trans, quats, t, self.tolerance)
                if m is None:
                    return None
            out = m @ out
        return out

    def coverage(self, frame: str) -> tuple[float, float] | None:
        """Time span of the dynamic samples on ``frame``'s path to the root, or None if all static."""
        spans = []
        for child in self._chain(frame.lstrip("/"))[:-1]:
            edge = self._edges[child]
            if not edge.static:
                times = edge.arrays()[0]
                spans.append((float(times[0]), float(times[-1])))
        if not spans:
            return None
        return max(s[0] for s in spans), min(s[1] for s in spans)
