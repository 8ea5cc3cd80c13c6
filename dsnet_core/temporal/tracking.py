"""The "DS-Net + tracking" baseline: single-frame instances linked frame to frame.

Each frame's 3D instances (from k = 1 DS-Net) are reduced to centroids in world coordinates
(the LiDAR-frame pose compensates ego motion). Live tracks predict where they are now — the last
centroid, plus a constant-velocity step when enabled — and are associated with the detections
greedily, closest pair first (MOST-style), within ``max_distance`` metres and only between
compatible classes. Unmatched detections start tracks with ids from one counter per sequence;
a track unseen for more than ``max_age`` frames ends and its id is never handed out again.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass

import numpy as np

from dsnet_core.labels import LabelMap, load_label_map
from dsnet_core.temporal.stitching import MAX_ID, StitchError

# SemanticKITTI train ids that may be confused frame to frame: vehicles, two-wheelers with and
# without rider, persons.
KITTI_COMPATIBLE: tuple[tuple[int, ...], ...] = ((1, 4, 5), (2, 7), (3, 8), (6,))


@dataclass
class Track:
    """A live track: world centroid ``(x, y, z)`` metres, velocity metres per time unit."""

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
    """Greedy centroid tracker for one sequence; ``add_frame`` returns the frame's final label.

    Args:
        label_map: dataset label map (default SemanticKITTI).
        max_distance: association gate between prediction and detection, metres.
        max_age: frames a track may go unseen and still be matched.
        constant_velocity: predict with the track's last velocity.
        compatible: groups of train ids that may be associated with each other (default
            :data:`KITTI_COMPATIBLE`; a class in no group is compatible only with itself).
    """

    def __init__(
        self,
        label_map: LabelMap | None = None,
        *,
        max_distance: float = 2.0,
        max_age: int = 2,
        constant_velocity: bool = True,
        compatible: Sequence[Sequence[int]] = KITTI_COMPATIBLE,
    ) -> None:
        self.label_map = label_map or load_label_map("semantic-kitti")
        self.max_distance = float(max_distance)
        self.max_age = int(max_age)
        self.constant_velocity = bool(constant_velocity)
        self._group = np.arange(self.label_map.num_classes) + 1000  # each class its own group
        for g, classes in enumerate(compatible):
            self._group[list(classes)] = g
        self.next_id = 1
        self.n_frames = 0
        self.tracks: list[Track] = []

    def add_frame(
        self,
        xyz: np.ndarray,
        semantic: np.ndarray,
        instance: np.ndarray,
        pose: np.ndarray | None = None,
        time: float | None = None,
        thing: np.ndarray | None = None,
    ) -> np.ndarray:
        """Associate one frame's instances with the live tracks.

        Args:
            xyz: ``(N, 3)`` points in the sensor frame, metres.
            semantic: ``(N,) int`` train ids. instance: ``(N,) int`` raw ids, 0 = none.
            pose: ``(4, 4)`` LiDAR-frame pose (sensor → world); None = identity (no ego motion).
            time: frame time (seconds or frame index); None = the frame's index in this sequence.
            thing: ``(N,) bool``, or None to derive it from ``semantic``.

        Returns:
            ``(N,) uint32`` label: raw semantic | track id << 16.

        Raises:
            StitchError: more than 65 535 ids in the sequence.
        """
        semantic = np.asarray(semantic, dtype=np.int64)
        instance = np.asarray(instance, dtype=np.int64)
        thing = self.label_map.is_thing()[semantic] if thing is None else np.asarray(thing, dtype=bool)
        t = float(self.n_frames if time is None else time)
        ids, cent, cls = instance_centroids(np.asarray(xyz)[:, :3], semantic, instance, thing)
        if pose is not None:
            cent = cent @ np.asarray(pose)[:3, :3].T + np.asarray(pose)[:3, 3]
        groups = self._group[cls]
        assigned = self._associate(cent, groups, t)
        tid = np.zeros(ids.size, np.int64)
        for det, track in assigned.items():
            tid[det] = track.id
        for det in range(ids.size):
            if det not in assigned:
                if self.next_id > MAX_ID:
                    raise StitchError(f"more than {MAX_ID} instance ids in one sequence")
                tid[det] = self.next_id
                self.tracks.append(Track(self.next_id, int(groups[det]), tuple(cent[det]), None, t))
                self.next_id += 1
        self.n_frames += 1
        out = np.zeros(instance.shape, np.int64)
        sel = thing & (instance > 0)
        out[sel] = tid[np.searchsorted(ids, instance[sel])]
        return self.label_map.to_raw(semantic) | (out.astype(np.uint32) << 16)

    def _predict(self, track: Track, t: float) -> np.ndarray:
        p = np.asarray(track.position)
        if self.constant_velocity and track.velocity is not None:
            p = p + np.asarray(track.velocity) * (t - track.time)
        return p

    def _associate(self, cent: np.ndarray, groups: np.ndarray, t: float) -> dict[int, Track]:
        pairs = []
        for ti, track in enumerate(self.tracks):
            pred = self._predict(track, t)
            dist = np.linalg.norm(cent - pred, axis=1) if cent.size else np.zeros(0)
            for det in np.flatnonzero((dist <= self.max_distance) & (groups == track.group)).tolist():
                pairs.append((float(dist[det]), track.id, ti, det))
        pairs.sort()
        assigned: dict[int, Track] = {}
        used: set[int] = set()
        for _, _, ti, det in pairs:
            if ti in used or det in assigned:
                continue
            track = self.tracks[ti]
            dt = t - track.time
            new = cent[det]
            track.velocity = tuple((new - np.asarray(track.position)) / dt) if dt > 0 else track.velocity
            track.position, track.time, track.misses = tuple(new), t, 0
            assigned[det] = track
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
            "next_id": self.next_id,
            "n_frames": self.n_frames,
            "tracks": [asdict(t) for t in self.tracks],
            "config": {
                "max_distance": self.max_distance,
                "max_age": self.max_age,
                "constant_velocity": self.constant_velocity,
            },
            "group": self._group.tolist(),
        }

    @classmethod
    def from_state(cls, state: Mapping, label_map: LabelMap | None = None) -> Tracker:
        """Rebuild a tracker from :meth:`state_dict` output."""
        tr = cls(label_map, **state["config"])
        tr._group = np.asarray(state["group"], dtype=np.int64)
        tr.next_id, tr.n_frames = int(state["next_id"]), int(state["n_frames"])
        for t in state["tracks"]:
            vel = None if t["velocity"] is None else tuple(float(v) for v in t["velocity"])
            pos = tuple(float(v) for v in t["position"])
            tr.tracks.append(
                Track(int(t["id"]), int(t["group"]), pos, vel, float(t["time"]), int(t["misses"]))
            )
        return tr
