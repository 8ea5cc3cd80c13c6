"""Reader for ROS 2 bags (format ``rosbag``): sqlite3 (``.db3``) and MCAP storage, through the
pure-Python ``rosbags`` package (extra ``formats``).

ROOT is a bag (a rosbag2 folder with ``metadata.yaml``, or a bare ``.mcap``/``.db3`` file) and
one sequence, or a folder of bags, one sequence each (named by the bag's folder or file stem).
A frame is one ``sensor_msgs/msg/PointCloud2`` message of the chosen topic (``topic``; needed
only when the bag has several), in recording order; its ``frame_id`` is the header stamp in
nanoseconds (19 digits; the bag's log time where the header stamp is 0; ``_1``, ``_2``... on
repeats), its timestamp that stamp in seconds. Points with NaN/inf coordinates are dropped and
counted (:meth:`RosbagReader.dropped_points`).

Poses come from ``/tf`` and ``/tf_static``: the transform from ``fixed_frame`` (default ``map``,
else ``odom``, whichever the tree has) to each cloud's ``header.frame_id``, interpolated at the
cloud's stamp. Without such a transform the reader has no poses (``--estimate-poses`` applies);
a ``fixed_frame`` that was asked for and is missing, or a stamp outside the transforms' time
span (beyond ``tf_tolerance_s``), is an error. So are clouds of one topic in several frames
(``header.frame_id``) that no tf relates to a fixed frame: odometry over scans from different
sensors, or scans stacked in no common frame, would be wrong; every frame's pose is that error,
so ``dsnet describe`` names the frames and ``dsnet label`` refuses (or quarantines every frame
with ``--on-error skip``).

Not supported (yet): ROS 1 ``.bag`` files (not detected); compressed clouds
(``CompressedPointCloud2``); PointCloud2 fields with ``count`` > 1 (skipped); motion compensation
by per-point time; several LiDAR topics merged into one frame (one topic per run); labels (a bag
has none, so it is labelled but never scored).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np

from dsnet_core.errors import BagFormatError, MissingExtraError, PoseFormatError
from dsnet_core.io.intensity import CONVENTIONS, infer_convention, normalise_intensity
from dsnet_core.io.options import as_label_map
from dsnet_core.io.pointcloud2 import Cloud, decode_cloud
from dsnet_core.io.reader import FrameRef
from dsnet_core.io.tf import TfTree
from dsnet_core.labels import LabelMap

CLOUD_TYPES = ("sensor_msgs/msg/PointCloud2", "sensor_msgs/PointCloud2")
TF_TYPES = ("tf2_msgs/msg/TFMessage", "tf2_msgs/TFMessage")
STORAGE_SUFFIXES = (".mcap", ".db3")


def is_bag(path: Path) -> bool:
    """A rosbag2 folder (``metadata.yaml``) or a bare ``.mcap``/``.db3`` storage file."""
    if path.is_dir():
        return (path / "metadata.yaml").is_file()
    return path.is_file() and path.suffix.lower() in STORAGE_SUFFIXES


@dataclass(frozen=True)
class _Index:
    topic: str
    log_times: tuple[int, ...]  # ns, recording time of each cloud
    ranks: tuple[int, ...]  # position among clouds with the same log time
    stamps: tuple[int, ...]  # ns, header stamp (log time where the header says 0)
    cloud_frames: tuple[str, ...]
    tf: TfTree


class RosbagReader:
    """Reads PointCloud2 messages of ROS 2 bags (format ``rosbag``).

    Args:
        root: a bag, or a folder of bags.
        topic: the PointCloud2 topic (needed when a bag has several).
        fixed_frame: the world frame of the poses (default ``map``, else ``odom``).
        intensity: ``"auto"`` (by the field's datatype, floats by value on the first cloud) or a
            convention (:data:`dsnet_core.io.intensity.CONVENTIONS`).
        intensity_field: the intensity field (default ``intensity``, else ``reflectivity``).
        tf_tolerance_s: how far past the transforms' time span a cloud stamp may fall.
        label_map: accepted for interface symmetry (bags carry no labels).
    """

    format = "rosbag"

    def __init__(
        self,
        root: str | Path,
        topic: str | None = None,
        fixed_frame: str | None = None,
        intensity: str = "auto",
        intensity_field: str | None = None,
        tf_tolerance_s: float = 0.05,
        label_map: LabelMap | str | None = None,
    ) -> None:
        try:
            import rosbags  # noqa: F401
        except ImportError as exc:
            raise MissingExtraError("rosbags", "formats", "reading ROS 2 bags") from exc
        self.root = Path(root).resolve()
        if intensity != "auto" and intensity not in CONVENTIONS:
            raise BagFormatError(self.root, f"intensity must be 'auto' or one of {CONVENTIONS}")
        self.topic, self.fixed_frame, self._intensity = topic, fixed_frame, intensity
        self.intensity_field, self.tf_tolerance_s = intensity_field, tf_tolerance_s
        self.label_map = as_label_map(label_map, "semantic-kitti")
        if is_bag(self.root):
            self._bags = {self.root.stem if self.root.is_file() else self.root.name: self.root}
        else:
            self._bags = {
                (p.stem if p.is_file() else p.name): p for p in sorted(self.root.iterdir()) if is_bag(p)
            }
        if not self._bags:
            raise BagFormatError(self.root, "is neither a ROS 2 bag nor a folder of bags")
        self._index = cache(self._build_index)
        self._frames = cache(self._list_frames)
        self._poses = cache(self._load_poses)
        self._convention = cache(self._infer_convention)
        self._local = threading.local()
        self._dropped: dict[tuple[str, int], int] = {}

    # -- protocol ------------------------------------------------------------------------------
    def sequences(self) -> list[str]:
        return sorted(self._bags)

    def frames(self, sequence: str) -> list[FrameRef]:
        return list(self._frames(sequence))

    def intensity_convention(self, sequence: str) -> str:
        return self._convention(sequence)

    def scan(self, frame: FrameRef) -> np.ndarray:
        """float32 ``(N, 4)``: x, y, z (metres, the cloud's frame), remission 0–1; NaN returns dropped."""
        cloud = self._cloud(frame)
        out = np.empty((cloud.xyz.shape[0], 4), dtype=np.float32)
        out[:, :3] = cloud.xyz
        out[:, 3] = normalise_intensity(
            cloud.intensity, self._convention(frame.sequence), self._where(frame), len(out)
        )
        return out

    def sensor_fields(self, sequence: str) -> str:
        """The topic, the cloud frame(s) and the fields read (x y z and the intensity field)."""
        index = self._index(sequence)
        first = self._frames(sequence)[0]
        field = self._cloud(first).field or "(no intensity)"
        frames = self.cloud_frames(sequence)
        if len(frames) == 1:
            return f"x y z {field} (PointCloud2 {index.topic}, frame {index.cloud_frames[0]})"
        return f"x y z {field} (PointCloud2 {index.topic}, {len(frames)} frames: {_counts(frames)})"

    def pose_source(self, sequence: str) -> str | None:
        """``tf <fixed frame> -> <cloud frame(s)>``, or None when the bag's tf gives no poses."""
        if self._poses(sequence) is None:
            return None
        return f"tf {self.fixed_frame_of(sequence)} -> {', '.join(self.cloud_frames(sequence))}"

    def cloud_frames(self, sequence: str) -> dict[str, int]:
        """The clouds' ``header.frame_id`` values in order of first appearance, with their counts."""
        counts: dict[str, int] = {}
        for frame in self._index(sequence).cloud_frames:
            counts[frame] = counts.get(frame, 0) + 1
        return counts

    def dropped_points(self, frame: FrameRef) -> int:
        """NaN/inf returns dropped from a frame's cloud."""
        key = (frame.sequence, frame.index)
        if key not in self._dropped:
            self._cloud(frame)
        return self._dropped[key]

    def kept_points(self, frame: FrameRef) -> np.ndarray | None:
        """bool ``(M,)`` over the message's points: those :meth:`scan` hands out (None: all)."""
        return self._cloud(frame).keep

    def labels(self, frame: FrameRef, n_points: int | None = None) -> np.ndarray | None:
        return None

    def pose(self, frame: FrameRef) -> np.ndarray | None:
        """float64 ``(4, 4)``: cloud frame -> fixed frame at the cloud's stamp, or None without tf."""
        loaded = self._poses(frame.sequence)
        if loaded is None:
            return None
        if frame.index in loaded[1]:
            raise loaded[1][frame.index]
        return loaded[0][frame.index]

    def poses(self, sequence: str) -> np.ndarray | None:
        loaded = self._poses(sequence)
        if loaded is not None and loaded[1]:
            raise next(iter(loaded[1].values()))
        return None if loaded is None else loaded[0]

    def timestamp(self, frame: FrameRef) -> float | None:
        return self._index(frame.sequence).stamps[frame.index] * 1e-9

    def cloud_frame(self, frame: FrameRef) -> str:
        """The cloud's ``header.frame_id``."""
        return self._index(frame.sequence).cloud_frames[frame.index]

    # -- helpers -------------------------------------------------------------------------------
    def _bag(self, sequence: str) -> Path:
        if sequence not in self._bags:
            raise BagFormatError(self.root / sequence, "no such bag")
        return self._bags[sequence]

    def _where(self, frame: FrameRef) -> str:
        return f"{self._bag(frame.sequence)} [{self._index(frame.sequence).topic} @ {frame.frame_id}]"

    def _open(self, sequence: str) -> Any:
        """An open AnyReader for the bag (one per thread: sqlite connections are per thread)."""
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore

        cache_ = self._local.__dict__.setdefault("readers", {})
        if sequence not in cache_:
            path = self._bag(sequence)
            try:
                reader = AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
                reader.open()
            except Exception as exc:  # rosbags raises several unrelated types for unreadable bags
                raise BagFormatError(path, f"not a readable ROS 2 bag: {' '.join(str(exc).split())}") from exc
            cache_[sequence] = reader
        return cache_[sequence]

    def _topic(self, sequence: str, reader: Any) -> Any:
        path = self._bag(sequence)
        clouds = sorted({c.topic for c in reader.connections if c.msgtype in CLOUD_TYPES})
        if self.topic is not None:
            if self.topic not in clouds:
                raise BagFormatError(
                    path,
                    f"has no PointCloud2 topic {self.topic!r} "
                    f"(PointCloud2 topics: {', '.join(clouds) or 'none'})",
                )
            return [c for c in reader.connections if c.topic == self.topic]
        if len(clouds) != 1:
            if not clouds:
                topics = ", ".join(sorted({f"{c.topic} ({c.msgtype})" for c in reader.connections})) or "none"
                raise BagFormatError(path, f"has no sensor_msgs/msg/PointCloud2 topic (topics: {topics})")
            raise BagFormatError(
                path,
                f"has several PointCloud2 topics ({', '.join(clouds)}); "
                "choose one with --topic (reader option topic)",
            )
        return [c for c in reader.connections if c.topic == clouds[0]]

    def _build_index(self, sequence: str) -> _Index:
        reader = self._open(sequence)
        conns = self._topic(sequence, reader)
        tf_conns = [
            c for c in reader.connections if c.msgtype in TF_TYPES and c.topic in ("/tf", "/tf_static")
        ]
        cloud_ids = {id(c) for c in conns}
        tree = TfTree(self.tf_tolerance_s)
        log_times, ranks, stamps, frames = [], [], [], []
        for conn, log_time, raw in reader.messages(connections=conns + tf_conns):
            msg = self._deserialize(reader, raw, conn, sequence, log_time)
            if id(conn) in cloud_ids:
                stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
                ranks.append(ranks[-1] + 1 if log_times and log_times[-1] == log_time else 0)
                log_times.append(log_time)
                stamps.append(stamp or log_time)
                frames.append(msg.header.frame_id)
                continue
            for tr in msg.transforms:
                t, r = tr.transform.translation, tr.transform.rotation
                stamp = (tr.header.stamp.sec * 1_000_000_000 + tr.header.stamp.nanosec) * 1e-9  # as clouds'
                tree.add(
                    tr.header.frame_id,
                    tr.child_frame_id,
                    stamp,
                    (t.x, t.y, t.z),
                    (r.w, r.x, r.y, r.z),
                    static=conn.topic == "/tf_static",
                )
        if not log_times:
            raise BagFormatError(self._bag(sequence), f"topic {conns[0].topic} has no messages")
        return _Index(conns[0].topic, tuple(log_times), tuple(ranks), tuple(stamps), tuple(frames), tree)

    def _deserialize(self, reader: Any, raw: bytes, conn: Any, sequence: str, log_time: int) -> Any:
        try:
            return reader.deserialize(raw, conn.msgtype)
        except Exception as exc:  # a corrupt message: name the bag, topic and time
            raise BagFormatError(
                self._bag(sequence), f"message on {conn.topic} at {log_time} ns does not decode: {exc}"
            ) from exc

    def _list_frames(self, sequence: str) -> tuple[FrameRef, ...]:
        index = self._index(sequence)
        seen: dict[int, int] = {}
        refs = []
        for i, stamp in enumerate(index.stamps):
            k = seen[stamp] = seen.get(stamp, -1) + 1
            refs.append(FrameRef(sequence, f"{stamp:019d}" + (f"_{k}" if k else ""), i, self._bag(sequence)))
        return tuple(refs)

    def _cloud(self, frame: FrameRef) -> Cloud:
        index = self._index(frame.sequence)
        reader = self._open(frame.sequence)
        conns = [c for c in reader.connections if c.topic == index.topic]
        t = index.log_times[frame.index]
        hits = list(reader.messages(connections=conns, start=t, stop=t + 1))
        rank = index.ranks[frame.index]
        if rank >= len(hits):
            raise BagFormatError(self._bag(frame.sequence), f"message on {index.topic} at {t} ns vanished")
        conn, _, raw = hits[rank]
        cloud = decode_cloud(
            self._deserialize(reader, raw, conn, frame.sequence, t), self._where(frame), self.intensity_field
        )
        self._dropped[(frame.sequence, frame.index)] = cloud.dropped
        return cloud

    def _infer_convention(self, sequence: str) -> str:
        if self._intensity != "auto":
            return self._intensity
        first = self._frames(sequence)[0]
        return infer_convention(self._cloud(first).intensity, self._where(first))

    def fixed_frame_of(self, sequence: str) -> str | None:
        """The world frame of the sequence's poses, or None when the bag has no usable one."""
        tree = self._index(sequence).tf
        if self.fixed_frame is not None:
            if self.fixed_frame.lstrip("/") not in tree.frames():
                frames = ", ".join(sorted(tree.frames())) or "none"
                raise PoseFormatError(
                    self._bag(sequence), f"has no tf frame {self.fixed_frame!r} (tf frames: {frames})"
                )
            return self.fixed_frame.lstrip("/")
        return next((f for f in ("map", "odom") if f in tree.frames()), None)

    def _load_poses(self, sequence: str) -> tuple[np.ndarray, dict[int, PoseFormatError]] | None:
        """(poses ``(F, 4, 4)`` with NaN rows where no transform exists, the errors of those rows)."""
        index = self._index(sequence)
        fixed = self.fixed_frame_of(sequence)
        frames = self.cloud_frames(sequence)
        if fixed is None or not any(index.tf.connected(fixed, f) for f in frames):
            if self.fixed_frame is not None:
                raise PoseFormatError(
                    self._bag(sequence),
                    f"tf does not connect {fixed} to the cloud frame{'s' if len(frames) > 1 else ''} "
                    f"{', '.join(map(repr, frames))}",
                )
            if len(frames) == 1:
                return None  # one sensor frame, no poses: odometry (--estimate-poses) may give them
            tf_frames = ", ".join(sorted(index.tf.frames())) or "none"
            error = PoseFormatError(
                self._bag(sequence),
                f"clouds on {index.topic} are in {len(frames)} frames ({_counts(frames)}) and no tf relates "
                f"them to a fixed frame (tf frames: {tf_frames}): their points cannot be put in one frame; "
                "record /tf (--fixed-frame names its world frame) or label one sensor's topic",
            )
            return np.full((len(index.stamps), 4, 4), np.nan), dict.fromkeys(range(len(index.stamps)), error)
        out = np.full((len(index.stamps), 4, 4), np.nan)
        errors = {}
        for i, (stamp, cloud_frame) in enumerate(zip(index.stamps, index.cloud_frames, strict=True)):
            pose = index.tf.lookup(fixed, cloud_frame, stamp * 1e-9)
            if pose is None:
                span = index.tf.coverage(cloud_frame)
                where = "not connected" if span is None else f"tf covers [{span[0]:.6f}, {span[1]:.6f}] s"
                errors[i] = PoseFormatError(
                    self._bag(sequence),
                    f"no transform {fixed} <- {cloud_frame} for frame {i} at {stamp * 1e-9:.6f} s ({where})",
                )
            else:
                out[i] = pose
        return out, errors


def _counts(frames: dict[str, int]) -> str:
    return ", ".join(f"{name} ×{n}" for name, n in frames.items())
