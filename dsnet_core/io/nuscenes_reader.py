"""Reader for nuScenes logs (format ``nuscenes``), parsing the ``v1.0-*`` JSON tables directly::

ROOT/v1.0-*/{scene,sample,sample_data,ego_pose,calibrated_sensor,sensor,category}.json
ROOT/v1.0-*/{panoptic,lidarseg}.json               (optional ground truth indexes)
ROOT/samples/LIDAR_TOP/*.pcd.bin                   float32 (N, 5): x, y, z, intensity 0–255, ring
ROOT/sweeps/LIDAR_TOP/*.pcd.bin                    the same, between keyframes
ROOT/panoptic/v1.0-*/<sd token>_panoptic.npz       uint16 general class * 1000 + instance
ROOT/lidarseg/v1.0-*/<sd token>_lidarseg.bin       uint8 general class

One sequence per scene (named by ``scene.name``), keyframes only unless ``sweeps=True``, in
timestamp order; a frame's ``frame_id`` is its LiDAR ``sample_data`` token. The LiDAR pose is
``ego_pose ∘ calibrated_sensor`` (sensor → ego → global), as nuscenes-devkit composes them;
timestamps are seconds (the tables store microseconds). Ground truth is read from the panoptic
file when the log has one for the frame, else from lidarseg (instance 0); labels are
``general class | instance << 16`` under the bundled ``panoptic-nuscenes`` label map, whose raw
ids are the general class indexes of ``category.json`` (checked on open).

nuscenes-devkit is not used: it pins numpy < 2 and pulls matplotlib and OpenCV, which would
downgrade this environment's numpy.

Not supported (yet): the devkit's multi-sweep accumulation (``sweeps=True`` makes each sweep a
frame of its own, not points merged into the keyframe; the ring and time-lag columns are not
used); more than one LiDAR channel per run; ground truth for sweeps (none exists) or instances in
lidarseg-only ground truth (instance 0: its thing PQ and tracking numbers mean nothing, mIoU does);
the map, radar and camera tables.
"""

from __future__ import annotations

from functools import cache
from pathlib import Path

import numpy as np

from dsnet_core.errors import ConfigError, LabelFormatError, ScanFormatError, TableFormatError
from dsnet_core.io.checks import check_points
from dsnet_core.io.intensity import normalise_intensity
from dsnet_core.io.nuscenes_tables import (
    TABLES,
    index_table,
    index_tables,
    is_lidar_record,
    load_table,
    rigid,
    short,
)
from dsnet_core.io.options import as_label_map
from dsnet_core.io.reader import FrameRef
from dsnet_core.labels import LabelMap


def find_versions(root: Path) -> list[str]:
    """Names of the ``v1.0-*`` table folders under ``root`` that hold ``sample_data.json``."""
    if not root.is_dir():
        return []
    return sorted(p.name for p in root.glob("v1.0-*") if (p / "sample_data.json").is_file())


class NuScenesReader:
    """Reads a nuScenes log through its JSON tables (format ``nuscenes``).

    Args:
        root: the folder holding ``v1.0-*/``, ``samples/`` and ``sweeps/``.
        version: the table folder (``v1.0-mini``); default the only one present.
        sweeps: also return the sweeps between keyframes (they have no ground truth).
        channel: the LiDAR sensor channel.
        label_map: accepted for interface symmetry; must be the ``panoptic-nuscenes`` map (or its name).

    Attributes:
        intensity: the source intensity convention (``uint8``); scans are returned in 0–1.
    """

    format = "nuscenes"
    intensity = "uint8"
    columns = 5

    def __init__(
        self,
        root: str | Path,
        version: str | None = None,
        sweeps: bool = False,
        channel: str = "LIDAR_TOP",
        label_map: LabelMap | str | None = None,
    ) -> None:
        self.root = Path(root).resolve()
        versions = find_versions(self.root)
        if version is None:
            if len(versions) != 1:
                found = ", ".join(versions) or "none"
                raise TableFormatError(
                    self.root, f"expected one v1.0-*/ table folder, found {found}; choose one with version="
                )
            version = versions[0]
        elif version not in versions:
            raise TableFormatError(self.root / version, f"no such table folder (found {', '.join(versions)})")
        self.version = version
        self.sweeps = bool(sweeps)
        self.channel = channel
        self.label_map = as_label_map(label_map, "panoptic-nuscenes")
        if self.label_map.name != "panoptic-nuscenes":
            raise ConfigError(
                f"{self.root}: nuScenes ground truth is read with the panoptic-nuscenes label map, "
                f"not {self.label_map.name}"
            )
        self._dir = self.root / version
        self._t = {name: self._load(name, required=True) for name in TABLES}
        self._gt = {name: self._load(name, required=False) for name in ("panoptic", "lidarseg")}
        self._check_categories()
        self._frames = cache(self._list_frames)
        index = index_tables(self._dir, self._t)
        self._sd, self._ego, self._calib = index["sample_data"], index["ego_pose"], index["calibrated_sensor"]
        self._label_files = {}
        for name in ("lidarseg", "panoptic"):  # panoptic wins where both exist
            table = self._gt[name] or []
            for token, rec in index_table(self._dir / f"{name}.json", table, "sample_data_token").items():
                self._label_files[token] = (name, rec["filename"])

    # -- protocol ------------------------------------------------------------------------------
    def sequences(self) -> list[str]:
        return sorted(s["name"] for s in self._t["scene"] if self._scene_frames(s["token"]))

    def frames(self, sequence: str) -> list[FrameRef]:
        return list(self._frames(sequence))

    def scan(self, frame: FrameRef) -> np.ndarray:
        """float32 ``(N, 4)``: x, y, z (metres, LiDAR frame), remission 0–1 (intensity / 255)."""
        path = self._exists(frame.scan_path, frame.frame_id)
        raw = path.read_bytes()
        if len(raw) % (4 * self.columns):
            raise ScanFormatError(
                path,
                f"size {len(raw)} bytes is not a multiple of {4 * self.columns} (float32 × {self.columns})",
            )
        pts = np.frombuffer(raw, dtype=np.float32).reshape(-1, self.columns)
        check_points(path, pts[:, :3])
        out = np.empty((pts.shape[0], 4), dtype=np.float32)
        out[:, :3] = pts[:, :3]
        out[:, 3] = normalise_intensity(pts[:, 3], self.intensity, path)
        return out

    def labels(self, frame: FrameRef, n_points: int | None = None) -> np.ndarray | None:
        """uint32 ``(N,)``: general class | instance << 16, or None for a frame without ground truth."""
        if frame.label_path is None:
            return None
        path = self._exists(frame.label_path, frame.frame_id)
        if path.name.endswith("_panoptic.npz"):
            from dsnet_core.metrics.nuscenes import read_panoptic_npz

            pan = read_panoptic_npz(path).astype(np.uint32)
            general, instance = pan // 1000, pan % 1000
        else:
            general = np.fromfile(path, dtype=np.uint8).astype(np.uint32)
            instance = np.zeros_like(general)
        if n_points is None:
            n_points = self._exists(frame.scan_path, frame.frame_id).stat().st_size // (4 * self.columns)
        if general.shape[0] != n_points:
            raise LabelFormatError(path, f"has {general.shape[0]} labels but the scan has {n_points} points")
        unknown = np.setdiff1d(np.unique(general), list(self.label_map.learning_map))
        if unknown.size:
            raise LabelFormatError(
                path, f"general class ids {unknown[:10].tolist()} are not nuScenes classes"
            )
        return general | (instance << 16)

    def pose(self, frame: FrameRef) -> np.ndarray | None:
        """float64 ``(4, 4)``: LiDAR → global, ``ego_pose ∘ calibrated_sensor``.

        Raises:
            TableFormatError: a record it needs is missing, or holds no 3 finite translation
                values or no unit quaternion (naming the table file and the record's token).
        """
        sd = self._sd[frame.frame_id]
        ego = self._record(self._ego, sd["ego_pose_token"], "ego_pose", frame.frame_id)
        cal = self._record(self._calib, sd["calibrated_sensor_token"], "calibrated_sensor", frame.frame_id)
        return rigid(self._dir / "ego_pose.json", ego) @ rigid(self._dir / "calibrated_sensor.json", cal)

    def poses(self, sequence: str) -> np.ndarray | None:
        return np.stack([self.pose(f) for f in self.frames(sequence)])

    def timestamp(self, frame: FrameRef) -> float | None:
        return self._sd[frame.frame_id]["timestamp"] / 1e6

    def intensity_convention(self, sequence: str) -> str:
        return self.intensity

    def sensor_fields(self, sequence: str) -> str:
        """The per-point fields of the source scans."""
        return f"x y z intensity ring (float32 N×{self.columns}, {self.channel})"

    def pose_source(self, sequence: str) -> str | None:
        """Where the poses come from (every nuScenes frame has one)."""
        return f"ego_pose ∘ calibrated_sensor ({self.version} tables)"

    # -- helpers -------------------------------------------------------------------------------
    def _load(self, name: str, required: bool) -> list[dict] | None:
        return load_table(self._dir / f"{name}.json", name, required)

    def _check_categories(self) -> None:
        if not any(self._gt.values()):
            return
        path = self._dir / "category.json"
        for rec in self._t["category"]:
            if "index" not in rec:
                raise TableFormatError(
                    path, f"category {rec.get('name')!r} has no 'index' (not nuScenes-lidarseg)"
                )
            if type(rec["index"]) is not int:
                raise TableFormatError(
                    path,
                    f"category {rec.get('name')!r} has index {short(rec['index'])}, expected an integer",
                )
            want = self.label_map.labels.get(rec["index"])
            if want != rec["name"]:
                raise TableFormatError(
                    path, f"category index {rec['index']} is {rec['name']!r}, the label map says {want!r}"
                )

    def _scene_frames(self, scene_token: str) -> list[dict]:
        return self._by_scene().get(scene_token, [])

    @cache  # noqa: B019 - one reader per log, the index lives as long as it
    def _by_scene(self) -> dict[str, list[dict]]:
        sensors = {s["token"] for s in self._t["sensor"] if s.get("channel") == self.channel}
        lidar_cal = {c["token"] for c in self._t["calibrated_sensor"] if c["sensor_token"] in sensors}
        sample_scene = {s["token"]: s["scene_token"] for s in self._t["sample"]}
        out: dict[str, list[dict]] = {}
        path = self._dir / "sample_data.json"
        for i, sd in enumerate(self._t["sample_data"]):
            if not is_lidar_record(path, i, sd, lidar_cal):
                continue
            if self.sweeps or sd["is_key_frame"]:
                scene = sample_scene.get(sd["sample_token"])
                if scene is None:
                    raise TableFormatError(
                        self._dir / "sample_data.json",
                        f"sample_data {sd['token']} names sample {sd['sample_token']}, "
                        "which sample.json lacks",
                    )
                out.setdefault(scene, []).append(sd)
        for records in out.values():
            records.sort(key=lambda r: (r["timestamp"], r["token"]))
        return out

    def _list_frames(self, sequence: str) -> tuple[FrameRef, ...]:
        scenes = [s for s in self._t["scene"] if s["name"] == sequence]
        if not scenes:
            raise TableFormatError(self._dir / "scene.json", f"no scene named {sequence!r}")
        refs = []
        for i, sd in enumerate(self._scene_frames(scenes[0]["token"])):
            label = self._label_files.get(sd["token"])
            refs.append(
                FrameRef(
                    sequence=sequence,
                    frame_id=sd["token"],
                    index=i,
                    scan_path=self.root / sd["filename"],
                    label_path=None if label is None else self.root / label[1],
                )
            )
        return tuple(refs)

    def _exists(self, path: Path, token: str) -> Path:
        if not path.is_file():
            raise TableFormatError(
                path, f"listed by {self.version}'s tables for sample_data {token} but the file is missing"
            )
        return path

    def _record(self, table: dict[str, dict], token: str, name: str, sd_token: str) -> dict:
        if token not in table:
            raise TableFormatError(
                self._dir / f"{name}.json", f"has no record {token} (named by sample_data {sd_token})"
            )
        return table[token]
