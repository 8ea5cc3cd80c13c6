"""Sequence-wide instance ids in 16 bits: handed out from a counter, recycled once it runs out.

A SemanticKITTI label keeps its instance id in the upper 16 bits, so a sequence has at most
:data:`MAX_ID` (65 535) ids at any one time. The temporal stages (``stitch``, ``track``) hand ids
out from one counter per sequence, 1, 2, 3, ... ; a model that opens ~60 ids per frame exhausts it
after ~1 100 frames. From then on :class:`IdPool` hands an id out again, the least recently used
first, and only once it has been unused for more than ``reuse_after`` frames: a stage marks every
id it still uses in a frame (:meth:`IdPool.touch`: the stitcher's carried ids, the tracker's live
and coasting tracks), so an id is never handed out while its track may still be matched. Until the
counter runs out nothing changes: ids are 1, 2, 3, ... in the order they were asked for.

Each hand-out of an id is a *generation* of it (0 the first time). A track is named by its *key*
``id | generation << 16`` (:func:`track_key`), equal to its id until ids are reused. Labels carry
only the id; the temporal stages' track tables carry the generation and the first frame of each
hand-out, and :class:`Generations` maps a frame's ids back to keys (generations of one id never
share a frame: the later one starts more than ``reuse_after`` frames after the earlier one ended).
"""

from __future__ import annotations

import base64
import zlib
from collections import OrderedDict
from collections.abc import Iterable, Mapping

import numpy as np

from dsnet_core.errors import DsnetError

MAX_ID = 0xFFFF
"""The largest instance id of a label (its upper 16 bits); 0 means none."""
ID_BITS = 16
"""A track key's lower bits: the id. The bits above hold the generation."""
REUSE_AFTER = 100
"""Default frames an id stays unused before it may be handed out again."""


class IdSpaceExhausted(DsnetError):
    """No instance id can be handed out: all 65 535 were in use within the reuse window."""


def track_key(ids: np.ndarray | int, generation: np.ndarray | int) -> np.ndarray | int:
    """``id | generation << 16``: the name of one hand-out of an id (the id itself for generation 0)."""
    return ids | (generation << ID_BITS)


def key_id(keys: np.ndarray | int) -> np.ndarray | int:
    """The label id of track keys (their lower 16 bits)."""
    return keys & MAX_ID


def key_generation(keys: np.ndarray | int) -> np.ndarray | int:
    """The generation of track keys (their bits above 16)."""
    return keys >> ID_BITS


def pack(values: np.ndarray) -> str:
    """int64 array -> base64 of zlib-compressed little-endian bytes (JSON-safe)."""
    return base64.b64encode(zlib.compress(np.asarray(values).astype("<i8").tobytes(), 6)).decode("ascii")


def unpack(text: str) -> np.ndarray:
    """The inverse of :func:`pack`: an ``int64`` array."""
    return np.frombuffer(zlib.decompress(base64.b64decode(text)), dtype="<i8").astype(np.int64)


class IdPool:
    """The ids of one sequence: a counter from 1 to :data:`MAX_ID`, then the least recently used id
    unused for more than ``reuse_after`` frames.

    Frames are any non-decreasing clock of the caller (frame ranks, positions in the sequence).

    Args:
        reuse_after: frames an id must stay unused (not touched) before it is handed out again (≥ 1).
    """

    def __init__(self, reuse_after: int = REUSE_AFTER) -> None:
        if int(reuse_after) < 1:
            raise ValueError(f"reuse_after must be at least 1 frame, got {reuse_after}")
        self.reuse_after = int(reuse_after)
        self.next_id = 1
        self.reused = 0  # hand-outs of an id that had been handed out before
        self.clock = 0  # the latest frame touched
        self._last: OrderedDict[int, int] = OrderedDict()  # id -> last frame used, oldest first
        self._generation: dict[int, int] = {}  # ids handed out more than once -> latest generation

    def take(self, frame: int, until: int | None = None) -> int:
        """Hand out an id for a track that starts in ``frame`` and is in use through ``until``.

        Returns:
            The track key (``id | generation << 16``; the id while the counter lasts).

        Raises:
            IdSpaceExhausted: every id was used after ``frame - reuse_after - 1``.
        """
        if self.next_id <= MAX_ID:
            tid = self.next_id
            self.next_id += 1
        else:
            tid, last = next(iter(self._last.items()))
            if frame - last <= self.reuse_after:
                raise IdSpaceExhausted(
                    f"no instance id free at frame {frame}: all {MAX_ID} ids were in use within the last "
                    f"{self.reuse_after} frames (the 16 bits of a SemanticKITTI label); lower the stage's "
                    "id_reuse_after or split the sequence"
                )
            del self._last[tid]
            self._generation[tid] = self._generation.get(tid, 0) + 1
            self.reused += 1
        self.touch((tid,), frame if until is None else until)
        return int(track_key(tid, self._generation.get(tid, 0)))

    def touch(self, ids: Iterable[int], frame: int) -> None:
        """Mark ids (or track keys) as used in ``frame`` (not earlier than any frame touched before)."""
        frame = int(frame)
        if frame < self.clock:
            raise ValueError(f"frame {frame} touched after frame {self.clock}: frames must not decrease")
        self.clock = frame
        last = self._last
        for key in ids:
            tid = int(key) & MAX_ID
            last[tid] = frame
            last.move_to_end(tid)

    def key(self, tid: int) -> int:
        """The key of the current hand-out of id ``tid``."""
        return int(track_key(tid, self._generation.get(tid, 0)))

    def state_dict(self) -> dict:
        """JSON-serialisable state (ids in least-recently-used order, delta-encoded and compressed)."""
        ids = np.fromiter(self._last.keys(), np.int64, len(self._last))
        last = np.fromiter(self._last.values(), np.int64, len(self._last))
        gen = np.array(sorted(self._generation.items()), np.int64).reshape(-1, 2)
        return {
            "reuse_after": self.reuse_after,
            "next_id": self.next_id,
            "reused": self.reused,
            "clock": self.clock,
            "lru_ids": pack(np.diff(ids, prepend=np.int64(0))),
            "lru_last": pack(np.diff(last, prepend=np.int64(0))),
            "generations": pack(gen.reshape(-1)),
        }

    @classmethod
    def from_state(cls, state: Mapping) -> IdPool:
        """Rebuild a pool from :meth:`state_dict` output."""
        pool = cls(state["reuse_after"])
        pool.next_id, pool.reused = int(state["next_id"]), int(state["reused"])
        pool.clock = int(state["clock"])
        ids = np.cumsum(unpack(state["lru_ids"])).tolist()
        last = np.cumsum(unpack(state["lru_last"])).tolist()
        pool._last = OrderedDict(zip(ids, last, strict=True))
        gen = unpack(state["generations"]).reshape(-1, 2).tolist()
        pool._generation = {int(i): int(g) for i, g in gen}
        return pool


class Generations:
    """Which hand-out of an id a frame's label means, from a track table's rows.

    Args:
        ids: ``(T,) int`` label ids of the rows.
        generations: ``(T,) int`` their generations.
        first_frames: ``(T,) int`` the first frame of each row's track.
    """

    def __init__(self, ids: np.ndarray, generations: np.ndarray, first_frames: np.ndarray) -> None:
        ids, gen, first = (np.asarray(a, np.int64).reshape(-1) for a in (ids, generations, first_frames))
        reused = np.isin(ids, ids[gen > 0])  # only ids handed out more than once need a look-up
        order = np.lexsort((first[reused], ids[reused]))
        self._ids, self._gen = ids[reused][order], gen[reused][order]
        self._start = (self._ids << 32) | first[reused][order]

    @classmethod
    def none(cls) -> Generations:
        """No id was ever reused: keys are the ids."""
        z = np.zeros(0, np.int64)
        return cls(z, z, z)

    @property
    def reused(self) -> bool:
        """Some id has more than one generation."""
        return self._ids.size > 0

    def keys(self, inst: np.ndarray, frame: int) -> np.ndarray:
        """``(N,) int64`` track keys of the ids ``inst`` ``(N,)`` (0 = none) seen in ``frame``: the
        generation whose first frame is the latest one not after ``frame`` (0 for ids without rows)."""
        inst = np.asarray(inst, np.int64)
        if not self.reused:
            return inst
        pos = np.searchsorted(self._start, (inst << 32) | int(frame), side="right") - 1
        hit = (pos >= 0) & (self._ids[np.maximum(pos, 0)] == inst) & (inst > 0)
        gen = np.where(hit, self._gen[np.maximum(pos, 0)], 0)
        return track_key(inst, gen)
