"""Greedy centre tracking across frames — the tracking algorithm of every method (``track``).

Each frame's instances are reduced to centres in world coordinates (the LiDAR-frame pose removes
ego motion): MOST's detected modal centres, or the centroids of any method's per-frame instances.
Every live track is compared with every detection of a compatible class (the label map's
``track_groups``):

- with a learned velocity (MOST), the detection is moved back by its velocity to the time of the
  track's last sighting and compared with the track's last position (CenterPoint's association:
  the previous frame's centres against this frame's centres displaced by the predicted velocity);
- without one, the track's position is predicted forward with its constant velocity (the
  difference of its last two positions), or stays where it was last seen.

Pairs within ``max_distance`` metres are taken greedily, closest first. Unmatched detections
start tracks with ids from one counter per sequence; a track unseen for more than ``max_age``
frames ends. Its id is not handed out again until the 65 535 ids of a label are exhausted; then
ids unused for more than ``reuse_after`` frames are recycled, least recently used first
(:class:`~dsnet_core.temporal.ids.IdPool`: a live or coasting track's id counts as used every
frame). Inside the tracker a track is named by its key ``id | generation << 16``; labels carry the
id. :meth:`Tracker.state_dict` / :meth:`Tracker.from_state` carry everything, so a resumed run
continues identically.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass

import numpy as np

from dsnet_core.labels import LabelMap, load_label_map
from dsnet_core.temporal.ids import REUSE_AFTER, IdPool, key_id
from dsnet_core.temporal.stitching import StitchError

STATE_VERSION = 3  # 2: no id pool (ids never reused)


@dataclass
class Track:
    """A live track (``id``: its key): world position (x, y, z) metres at ``time``, world velocity
    (m per time unit)."""

    id: int
    group: int
    position: tuple[float, float, float]
    velocity: tuple[float, float, float] | None
    time: float
    misses: int = 0


def instance_centroids(
    xyz: np.ndarray, semantic: np.ndarray, instance: np.ndarray, thing: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centroids of one frame's instances.

    Args:
        xyz: ``(N, 3) float`` points (metres). semantic: ``(N,) int`` train ids.
        instance: ``(N,) int`` raw ids (0 = none). thing: ``(N,) bool``.

    Returns:
        ``ids (M,) int64`` sorted, ``centroids (M, 3) float64``, ``classes (M,) int64`` (majority,
        ties to the lowest id).
    """
    sel = thing & (instance > 0)
    ids, inv = np.unique(instance[sel], return_inverse=True)
    if ids.size == 0:
        return ids.astype(np.int64), np.zeros((0, 3)), np.zeros(0, np.int64)
    n = np.bincount(inv).astype(np.float64)
    cent = (
        np.stack([np.bincount(inv, weights=xyz[sel, d].astype(np.float64)) for d in range(3)], 1) / n[:, None]
    )
    sem = semantic[sel].astype(np.int64)
    hist = np.zeros((ids.size, int(sem.max()) + 1), np.int64)
    np.add.at(hist, (inv, sem), 1)
    return ids.astype(np.int64), cent, hist.argmax(1)


class Tracker:
    """Greedy centre tracker for one sequence.

    Args:
        label_map: dataset label map (default SemanticKITTI); its ``track_groups`` gate classes.
        max_distance: association gate, metres.
        max_age: frames a track may go unseen and still be matched.
        constant_velocity: without a learned velocity, predict with the track's last velocity.
        compatible: groups of train ids overriding the label map's ``track_groups``.
        reuse_after: once the 65 535 ids are exhausted, an id is handed out again only after this
            many frames without a live track holding it.
    """

    def __init__(
        self,
        label_map: LabelMap | None = None,
        *,
        max_distance: float = 2.0,
        max_age: int = 2,
        constant_velocity: bool = True,
        compatible: Sequence[Sequence[int]] | None = None,
        reuse_after: int = REUSE_AFTER,
    ) -> None:
        self.label_map = label_map or load_label_map("semantic-kitti")
        self.max_distance = float(max_distance)
        self.max_age = int(max_age)
        self.constant_velocity = bool(constant_velocity)
        if compatible is None:
            self._group = self.label_map.track_group_of()
        else:
            self._group = np.arange(self.label_map.num_classes) + 1000  # each class its own group
            for g, classes in enumerate(compatible):
                self._group[list(classes)] = g
        self.ids = IdPool(reuse_after)
        self.n_frames = 0
        self.tracks: list[Track] = []

    @property
    def next_id(self) -> int:
        """The id the counter hands out next (beyond 65 535: ids are reused)."""
        return self.ids.next_id

    def add_detections(
        self,
        centres: np.ndarray,
        classes: np.ndarray,
        pose: np.ndarray | None = None,
        time: float | None = None,
        velocities: np.ndarray | None = None,
    ) -> np.ndarray:
        """Associate one frame's detections with the live tracks.

        Args:
            centres: ``(M, 3)`` centres in the sensor frame, metres.
            classes: ``(M,) int`` train ids.
            pose: ``(4, 4)`` LiDAR-frame pose (sensor → world); None = identity.
            time: frame time (seconds or frame index); None = the frame's index in this sequence.
            velocities: ``(M, 2)`` learned (x, y) velocities in the sensor frame (metres per time
                unit), or None for the constant-velocity model.

        Returns:
            ``(M,) int64`` track keys: ``id | generation << 16``, the track id until ids are reused
            (:func:`relabel` writes the id).

        Raises:
            IdSpaceExhausted: all 65 535 ids were in use within the last ``reuse_after`` frames.
        """
        t = float(self.n_frames if time is None else time)
        cent = np.asarray(centres, np.float64).reshape(-1, 3)
        vel = None
        rot = np.eye(3) if pose is None else np.asarray(pose, np.float64)[:3, :3]
        if pose is not None:
            cent = cent @ rot.T + np.asarray(pose, np.float64)[:3, 3]
        if velocities is not None:
            v = np.zeros((cent.shape[0], 3))
            v[:, :2] = np.asarray(velocities, np.float64).reshape(-1, 2)
            vel = v @ rot.T
        groups = self._group[np.asarray(classes, np.int64)]
        assigned = self._associate(cent, groups, vel, t)
        tid = np.zeros(cent.shape[0], np.int64)
        for det in range(cent.shape[0]):
            if det in assigned:
                tid[det] = assigned[det]
                continue
            tid[det] = self.ids.take(self.n_frames)
            v0 = None if vel is None else tuple(float(x) for x in vel[det])
            self.tracks.append(Track(int(tid[det]), int(groups[det]), tuple(cent[det]), v0, t))
        self.ids.touch((track.id for track in self.tracks), self.n_frames)  # live and coasting tracks
        self.n_frames += 1
        return tid

    def add_frame(
        self,
        xyz: np.ndarray,
        semantic: np.ndarray,
        instance: np.ndarray,
        pose: np.ndarray | None = None,
        time: float | None = None,
        thing: np.ndarray | None = None,
    ) -> np.ndarray:
        """Track one frame's per-point instances by their centroids (constant velocity).

        Args:
            xyz: ``(N, 3)`` points in the sensor frame, metres.
            semantic: ``(N,) int`` train ids. instance: ``(N,) int`` raw ids, 0 = none.
            pose, time: as :meth:`add_detections`. thing: ``(N,) bool``, or None from ``semantic``.

        Returns:
            ``(N,) uint32`` label: raw semantic | track id << 16.
        """
        semantic = np.asarray(semantic, dtype=np.int64)
        instance = np.asarray(instance, dtype=np.int64)
        thing = self.label_map.is_thing()[semantic] if thing is None else np.asarray(thing, dtype=bool)
        ids, cent, cls = instance_centroids(np.asarray(xyz)[:, :3], semantic, instance, thing)
        tid = self.add_detections(cent, cls, pose, time)
        return relabel(self.label_map, semantic, instance, ids, tid, thing)

    def _associate(
        self, cent: np.ndarray, groups: np.ndarray, vel: np.ndarray | None, t: float
    ) -> dict[int, int]:
        pairs = []
        for ti, track in enumerate(self.tracks):
            dt = t - track.time
            if vel is not None:  # detections displaced back to the track's last sighting
                dist = np.linalg.norm(cent - vel * dt - np.asarray(track.position), axis=1)
            else:
                pred = np.asarray(track.position)
                if self.constant_velocity and track.velocity is not None:
                    pred = pred + np.asarray(track.velocity) * dt
                dist = np.linalg.norm(cent - pred, axis=1) if cent.size else np.zeros(0)
            for det in np.flatnonzero((dist <= self.max_distance) & (groups == track.group)).tolist():
                pairs.append((float(dist[det]), track.id, ti, det))
        pairs.sort()
        assigned: dict[int, int] = {}
        used: set[int] = set()
        for _, _, ti, det in pairs:
            if ti in used or det in assigned:
                continue
            track = self.tracks[ti]
            dt = t - track.time
            new = cent[det]
            if vel is not None:
                track.velocity = tuple(float(x) for x in vel[det])
            elif dt > 0:
                track.velocity = tuple((new - np.asarray(track.position)) / dt)
            track.position, track.time, track.misses = tuple(new), t, 0
            assigned[det] = track.id
            used.add(ti)
        kept = []
        for ti, track in enumerate(self.tracks):
            if ti not in used:
                track.misses += 1
            if track.misses <= self.max_age:
                kept.append(track)
        self.tracks = kept
        return assigned

    def state_dict(self) -> dict:
        """JSON-serialisable state; :meth:`from_state` continues identically."""
        return {
            "version": STATE_VERSION,
            "label_map": self.label_map.name,
            "ids": self.ids.state_dict(),
            "n_frames": self.n_frames,
            "tracks": [asdict(t) for t in self.tracks],
            "config": {
                "max_distance": self.max_distance,
                "max_age": self.max_age,
                "constant_velocity": self.constant_velocity,
                "reuse_after": self.ids.reuse_after,
            },
            "group": self._group.tolist(),
        }

    @classmethod
    def from_state(cls, state: Mapping, label_map: LabelMap | None = None) -> Tracker:
        """Rebuild a tracker from :meth:`state_dict` output.

        Raises:
            StitchError: an unknown state version or another label map's state.
        """
        if state.get("version") != STATE_VERSION:
            raise StitchError(f"track state version {state.get('version')!r}, expected {STATE_VERSION}")
        tr = cls(label_map, **state["config"])
        if "label_map" in state and state["label_map"] != tr.label_map.name:
            raise StitchError(
                f"track state is for label map {state['label_map']!r}, not {tr.label_map.name!r}"
            )
        tr._group = np.asarray(state["group"], dtype=np.int64)
        tr.ids, tr.n_frames = IdPool.from_state(state["ids"]), int(state["n_frames"])
        for t in state["tracks"]:
            vel = None if t["velocity"] is None else tuple(float(v) for v in t["velocity"])
            pos = tuple(float(v) for v in t["position"])
            tr.tracks.append(
                Track(int(t["id"]), int(t["group"]), pos, vel, float(t["time"]), int(t["misses"]))
            )
        return tr


def relabel(
    label_map: LabelMap,
    semantic: np.ndarray,
    instance: np.ndarray,
    ids: np.ndarray,
    track_ids: np.ndarray,
    thing: np.ndarray | None = None,
) -> np.ndarray:
    """Per-point label with track ids: ``(N,) uint32`` raw semantic | track id << 16.

    Args:
        semantic: ``(N,)`` train ids. instance: ``(N,)`` frame-local ids (0 = none).
        ids: ``(M,)`` sorted frame-local ids that were tracked; track_ids: ``(M,)`` their track ids
            or keys (``id | generation << 16``: the label gets the id).
        thing: ``(N,) bool`` points that may carry an id (default: thing classes).
    """
    semantic = np.asarray(semantic, np.int64)
    instance = np.asarray(instance, np.int64)
    thing = label_map.is_thing()[semantic] if thing is None else thing
    out = np.zeros(instance.shape, np.int64)
    sel = thing & (instance > 0) & np.isin(instance, ids)
    out[sel] = key_id(np.asarray(track_ids, np.int64))[np.searchsorted(ids, instance[sel])]
    return label_map.to_raw(semantic) | (out.astype(np.uint32) << 16)
