"""Per-frame values of any stage, for a stage or the report: :class:`FrameValues`.

A frame stage's item is a frame already. A volume stage's points come from several frames; how is
declared by the stage that declares align's :data:`SOURCE` arrays (``source_frame``: the frame of
each point, ``source_index``: its index in that frame's scan) and records the volumes' ``windows``
(frame indices) in its plan. A frame belongs to the first volume that holds it (the ownership rule
of ``stitch``), and its values in that volume, put back in the scan's point order, are its values.
Consumers (``track``, ``refine``, ``prior``, the report's frame confidence) ask this helper instead
of redoing the mapping; the mapping stage is found by its declarations (:func:`nearest`), not by
name.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from dsnet_core.temporal.align import split_volume
from storage.contract import ArraySpec

if TYPE_CHECKING:
    from storage.arrays import StageArrays
    from storage.run import RunStore
    from tasks.pipeline import Pipeline

SOURCE = (
    ArraySpec("source_frame", "int32", doc="frame index (sequence) of each point", codec="shuffle-lz4"),
    ArraySpec("source_index", "int32", doc="point index in its source scan", codec="shuffle-lz4"),
)
"""The declarations that map a volume's points to their frames (``align`` declares them)."""


def nearest(pipeline: Pipeline, name: str, wanted: tuple, item: str | None = None, itself: bool = False):
    """The nearest stage upstream of ``name`` (``name`` itself first when ``itself``) that declares
    every :class:`~storage.contract.ArraySpec` of ``wanted`` (and has ``item``, when given); None."""
    names = [*pipeline.upstream_closure(name), *([name] if itself else [])]
    for stage in reversed(names):
        spec = pipeline[stage]
        if (item is None or spec.item == item) and all(a in spec.arrays for a in wanted):
            return stage
    return None


class FrameValues:
    """Per-frame values of one sequence's stages, in each frame's scan order.

    Args:
        store, pipeline, sequence: the run.
        mapping: the volume stage declaring :data:`SOURCE` (None: only frame stages can be read).

    ``frame(arrays, f, names)`` caches the last volume read per stage (consumers read frames in
    order); a volume of one frame is its frame (align builds it in scan order) and is returned as
    read, without reading the mapping.
    """

    def __init__(self, store: RunStore, pipeline: Pipeline, sequence: str, mapping: str | None) -> None:
        self.mapping = mapping
        self.windows: list[list[int]] = []
        self.owner: dict[int, int] = {}
        self._source: StageArrays | None = None
        if mapping is not None:
            m = store.read_manifest(sequence, mapping)
            self.windows = [] if m is None else [[int(f) for f in w] for w in m.plan["windows"]]
            for v, w in enumerate(self.windows):
                for f in w:
                    self.owner.setdefault(f, v)
            self._source = store.arrays(sequence, pipeline[mapping].contract)
        self._cache: dict[str, tuple[int, tuple[str, ...], dict[int, dict[str, np.ndarray]]]] = {}

    @classmethod
    def near(cls, store: RunStore, pipeline: Pipeline, sequence: str, stage: str) -> FrameValues:
        """The helper for ``stage`` and what it reads: the mapping is the nearest volume stage at or
        upstream of ``stage`` declaring :data:`SOURCE`."""
        return cls(store, pipeline, sequence, nearest(pipeline, stage, SOURCE, "volume", itself=True))

    def frames(self) -> list[int]:
        """The frames the volumes hold, in order."""
        return sorted(self.owner)

    def source(self, volume: int) -> dict[str, np.ndarray]:
        """The mapping of one volume: int32 ``source_frame`` and ``source_index`` ``(P,)``."""
        if self._source is None:
            raise ValueError("no stage of the pipeline declares how volumes map to frames")
        return self._source.read_item(volume, ["source_frame", "source_index"])

    def frame(self, arrays: StageArrays, frame: int, names: list[str]) -> dict[str, np.ndarray] | None:
        """``names`` of ``arrays``' stage for ``frame``, ``(N_f, ...)`` in the scan's point order;
        None when no volume holds the frame. A frame stage's arrays are read as they are."""
        if arrays.contract.item == "frame":
            return arrays.read_item(frame, names)
        v = self.owner.get(frame)
        if v is None:
            return None
        if len(self.windows[v]) == 1:
            return arrays.read_item(v, names)
        key = arrays.contract.stage
        cached = self._cache.get(key)
        if cached is None or cached[0] != v or cached[1] != tuple(names):
            values = arrays.read_item(v, names)
            src = self.source(v)
            split = {n: split_volume(values[n], src["source_frame"], src["source_index"]) for n in names}
            per_frame = {int(f): {n: split[n][f] for n in names} for f in split[names[0]]} if names else {}
            cached = (v, tuple(names), per_frame)
            self._cache[key] = cached
        return cached[2].get(frame)

    def gather(
        self, volume: int, per_frame: Callable[[int], np.ndarray], dtype=None
    ) -> tuple[np.ndarray | None, int]:
        """The other way: values of one volume's points from each frame's ``(N_f, ...)`` values in
        scan order (``per_frame(f)``, asked once per frame, in order), as ``dtype`` (default the
        first frame's). Returns ``(values (P, ...) or
        None when the volume holds no point, P)``."""
        src = self.source(volume)
        sf, si = src["source_frame"], src["source_index"]
        out = None
        for f in np.unique(sf).tolist():
            p = per_frame(int(f))
            sel = sf == f
            if out is None:
                out = np.zeros((sf.shape[0], *p.shape[1:]), dtype or p.dtype)
            out[sel] = p[si[sel]]
        return out, int(sf.shape[0])
