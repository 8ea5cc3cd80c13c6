"""Re-encode a (pre-quantised) SemanticKITTI log in every input format, with independent writers:
numpy for raw ``.bin``/``.npy``/``.npz``, pypcd4 for PCD, plyfile for PLY, laspy (+lazrs) for
LAS/LAZ, the rosbags writer for ROS 2 bags, and JSON tables laid out as nuscenes-devkit
documents them. The readers under test share no code with these writers.
"""

from __future__ import annotations

import itertools
import json
from pathlib import Path

import numpy as np

from dsnet_core.io.geometry import matrix_to_quat
from dsnet_core.io.intensity import FULL_SCALE
from dsnet_core.io.nuscenes_export import SceneEncoder
from dsnet_core.io.semantickitti import SemanticKittiReader, write_frame, write_sequence_meta
from dsnet_core.synth.log import kitti_tr

SEQ = "00"


def quantised_log(
    src: Path,
    dst: Path,
    frames: int,
    convention: str = "unit",
    xyz_scale: float | None = None,
    decimals: int | None = None,
    every: int = 1,
) -> Path:
    """Copy the first ``frames`` frames of sequence 00 with remission on the convention's quantum
    (``k / scale`` in float32), with ``xyz_scale`` coordinates on that grid (LAS), and with
    ``decimals`` every value a fixed point of printing with that many decimals (ASCII PCD); with
    ``every`` > 1 only every n-th point (text formats parse slowly)."""
    ref = SemanticKittiReader(src)
    refs = ref.frames(SEQ)[:frames]
    seq_dir = dst / "sequences" / SEQ
    scale = FULL_SCALE[convention]
    for f in refs:
        scan, label = ref.scan(f)[::every].copy(), ref.labels(f)[::every]
        if scale is None:
            scan[:, 3] = 0
        elif convention != "unit":
            scan[:, 3] = np.round(scan[:, 3].astype(np.float64) * scale).astype(np.float32) / np.float32(
                scale
            )
        if xyz_scale is not None:
            scan[:, :3] = (np.round(scan[:, :3].astype(np.float64) / xyz_scale) * xyz_scale).astype(
                np.float32
            )
        if decimals is not None:
            for _ in range(2):  # printing then parsing converges after one pass; the second checks it
                text = " ".join(f"{v:.{decimals}f}" for v in scan.reshape(-1).tolist())
                scan = np.array(text.split(), dtype=np.float64).astype(np.float32).reshape(scan.shape)
        write_frame(seq_dir, f.frame_id, scan, label)
    times = np.array([ref.timestamp(f) for f in refs])
    write_sequence_meta(seq_dir, ref.poses(SEQ)[:frames], kitti_tr(), times)
    return dst


def frames_of(ref: SemanticKittiReader):
    """(frame id, scan, label, pose, time) of sequence 00."""
    for f in ref.frames(SEQ):
        yield f.frame_id, ref.scan(f), ref.labels(f), ref.pose(f), ref.timestamp(f)


def write_meta(ref: SemanticKittiReader, out: Path, poses: str = "kitti", times: bool = True) -> None:
    """``poses.txt`` (LiDAR 3×4, or TUM rows) and ``times.txt``, with numpy's text writer."""
    p = ref.poses(SEQ)
    t = np.array([ref.timestamp(f) for f in ref.frames(SEQ)])
    if poses == "kitti":
        np.savetxt(out / "poses.txt", p[:, :3].reshape(len(p), 12), fmt="%.17g")
    elif poses == "tum":
        q = np.array([matrix_to_quat(m[:3, :3]) for m in p])
        rows = np.column_stack([t, p[:, :3, 3], q[:, 1:], q[:, :1]])
        np.savetxt(out / "poses.tum", rows, fmt="%.17g", header="timestamp tx ty tz qx qy qz qw")
    if times:
        np.savetxt(out / "times.txt", t, fmt="%.17g")


def write_bin(ref, out: Path, columns: int = 4, labels: bool = False) -> Path:
    out.mkdir(parents=True)
    for fid, scan, label, _, _ in frames_of(ref):
        if columns == 5:  # nuScenes-like: intensity 0-255, ring index
            ring = (np.arange(len(scan)) % 32).astype(np.float32)
            rows = np.column_stack([scan[:, :3], np.round(scan[:, 3] * np.float32(255)), ring])
        else:
            rows = scan
        np.ascontiguousarray(rows, dtype=np.float32).tofile(out / f"{fid}.bin")
        if labels:
            label.astype(np.uint32).tofile(out / f"{fid}.label")
    write_meta(ref, out)
    return out


def write_numpy(ref, out: Path, kind: str) -> Path:
    out.mkdir(parents=True)
    for fid, scan, _, _, _ in frames_of(ref):
        if kind == "npy":
            np.save(out / f"{fid}.npy", scan)
        elif kind == "structured":
            arr = np.zeros(len(scan), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4")])
            for i, c in enumerate(("x", "y", "z", "intensity")):
                arr[c] = scan[:, i]
            np.save(out / f"{fid}.npy", arr)
        else:
            np.savez(out / f"{fid}.npz", x=scan[:, 0], y=scan[:, 1], z=scan[:, 2], intensity=scan[:, 3])
    write_meta(ref, out)
    return out


def write_pcd(ref, out: Path, encoding: str, intensity: str = "float32") -> Path:
    from pypcd4 import Encoding, PointCloud

    out.mkdir(parents=True)
    for fid, scan, _, _, _ in frames_of(ref):
        if intensity == "uint8":
            cols = [scan[:, 0], scan[:, 1], scan[:, 2], np.round(scan[:, 3] * 255).astype(np.uint8)]
            types = [np.float32, np.float32, np.float32, np.uint8]
        else:
            cols = [scan[:, 0], scan[:, 1], scan[:, 2], scan[:, 3]]
            types = [np.float32] * 4
        pc = PointCloud.from_points(cols, ("x", "y", "z", "intensity"), types)
        pc.save(out / f"{fid}.pcd", encoding=Encoding(encoding))
    write_meta(ref, out)
    return out


def write_ply(ref, out: Path, text: bool = False) -> Path:
    from plyfile import PlyData, PlyElement

    out.mkdir(parents=True)
    for fid, scan, _, _, _ in frames_of(ref):
        arr = np.zeros(len(scan), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4")])
        for i, c in enumerate(("x", "y", "z", "intensity")):
            arr[c] = scan[:, i]
        PlyData([PlyElement.describe(arr, "vertex")], text=text).write(str(out / f"{fid}.ply"))
    write_meta(ref, out)
    return out


def write_las(ref, out: Path, scale: float, laz: bool = False) -> Path:
    import laspy

    out.mkdir(parents=True)
    for fid, scan, _, _, _ in frames_of(ref):
        header = laspy.LasHeader(point_format=1, version="1.2")
        header.scales = np.array([scale] * 3)
        header.offsets = np.zeros(3)
        las = laspy.LasData(header)
        las.x, las.y, las.z = (scan[:, i].astype(np.float64) for i in range(3))
        las.intensity = np.round(scan[:, 3].astype(np.float64) * 65535).astype(np.uint16)
        las.write(str(out / f"{fid}.{'laz' if laz else 'las'}"))
    write_meta(ref, out)
    return out


def calib() -> np.ndarray:
    """A non-identity LiDAR → ego transform (roof mount, yawed and tilted)."""
    c, s = np.cos(0.3), np.sin(0.3)
    tilt = np.array([[1, 0, 0], [0, np.cos(0.05), -np.sin(0.05)], [0, np.sin(0.05), np.cos(0.05)]])
    m = np.eye(4)
    m[:3, :3] = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]) @ tilt
    m[:3, 3] = [0.94, 0.0, 1.84]
    return m


def write_nuscenes(
    ref, out: Path, version: str = "v1.0-mini", sweep_every: int = 0, world: np.ndarray | None = None
) -> dict[str, list[str]]:
    """A nuScenes log of sequence 00 as one scene; every ``sweep_every``-th frame (1-based) a sweep.

    Args:
        world: a global → first-LiDAR offset applied to every pose (moves the ego away from the origin).

    Returns:
        {"keyframes": sample_data tokens, "all": tokens in time order}.
    """
    tables: dict[str, list[dict]] = {
        name: []
        for name in (
            "attribute",
            "calibrated_sensor",
            "category",
            "ego_pose",
            "instance",
            "log",
            "map",
            "sample",
            "sample_annotation",
            "sample_data",
            "scene",
            "sensor",
            "visibility",
            "panoptic",
            "lidarseg",
        )
    }
    from dsnet_core.labels import load_label_map

    lm = load_label_map("panoptic-nuscenes")
    tables["category"] = [
        {"token": f"cat{i:02d}", "name": name, "description": "", "index": i}
        for i, name in sorted(lm.labels.items())
    ]
    tables["sensor"] = [{"token": "sensor-lidar", "channel": "LIDAR_TOP", "modality": "lidar"}]
    cal = calib()
    tables["calibrated_sensor"] = [
        {
            "token": "cal-lidar",
            "sensor_token": "sensor-lidar",
            "translation": cal[:3, 3].tolist(),
            "rotation": matrix_to_quat(cal[:3, :3]).tolist(),
            "camera_intrinsic": [],
        }
    ]
    tables["log"] = [
        {
            "token": "log0",
            "logfile": "synthetic",
            "vehicle": "synth",
            "date_captured": "2024-01-01",
            "location": "synth",
        }
    ]
    encoder = SceneEncoder("scene-0001")
    world = np.eye(4) if world is None else world
    samples, sds, key_tokens = [], [], []
    for i, (fid, scan, label, pose, t) in enumerate(frames_of(ref)):
        token = f"sd{i:04d}{fid}"
        key = not (sweep_every and (i + 1) % sweep_every == 0)
        if key:
            samples.append({"token": f"sample{i:04d}", "timestamp": round(t * 1e6), "scene_token": "scene0"})
        ego = world @ pose @ np.linalg.inv(cal)
        tables["ego_pose"].append(
            {
                "token": f"ego{i:04d}",
                "timestamp": round(t * 1e6),
                "rotation": matrix_to_quat(ego[:3, :3]).tolist(),
                "translation": ego[:3, 3].tolist(),
            }
        )
        folder = "samples" if key else "sweeps"
        filename = f"{folder}/LIDAR_TOP/synth__LIDAR_TOP__{fid}.pcd.bin"
        ring = (np.arange(len(scan)) % 32).astype(np.float32)
        rows = np.column_stack([scan[:, :3], np.round(scan[:, 3] * np.float32(255)), ring]).astype(np.float32)
        (out / filename).parent.mkdir(parents=True, exist_ok=True)
        rows.tofile(out / filename)
        sds.append(
            {
                "token": token,
                "sample_token": None,
                "ego_pose_token": f"ego{i:04d}",
                "calibrated_sensor_token": "cal-lidar",
                "timestamp": round(t * 1e6),
                "fileformat": "pcd",
                "is_key_frame": key,
                "height": 0,
                "width": 0,
                "filename": filename,
                "prev": "",
                "next": "",
            }
        )
        if key:
            key_tokens.append(token)
        if key and label is not None:
            pan = encoder.encode(label)
            name = f"panoptic/{version}/{token}_panoptic.npz"
            (out / name).parent.mkdir(parents=True, exist_ok=True)
            np.savez_compressed(out / name, data=pan)
            tables["panoptic"].append({"token": token, "sample_data_token": token, "filename": name})
    for s, nxt in zip(samples, [*samples[1:], None], strict=True):
        s["next"] = nxt["token"] if nxt else ""
    for s, prv in zip(samples, [None, *samples[:-1]], strict=True):
        s["prev"] = prv["token"] if prv else ""
    stamps = [s["timestamp"] for s in samples]
    for sd in sds:  # a sweep belongs to the next keyframe's sample (the last keyframe's at the end)
        j = min(int(np.searchsorted(stamps, sd["timestamp"])), len(samples) - 1)
        sd["sample_token"] = samples[j]["token"]
    for a, b in itertools.pairwise(sds):
        a["next"], b["prev"] = b["token"], a["token"]
    tables["sample"] = samples
    tables["sample_data"] = sds
    tables["scene"] = [
        {
            "token": "scene0",
            "log_token": "log0",
            "nbr_samples": len(samples),
            "first_sample_token": samples[0]["token"],
            "last_sample_token": samples[-1]["token"],
            "name": "scene-0001",
            "description": "synthetic",
        }
    ]
    (out / version).mkdir(parents=True, exist_ok=True)
    for name, records in tables.items():
        (out / version / f"{name}.json").write_text(json.dumps(records, indent=0))
    return {"keyframes": key_tokens, "all": [sd["token"] for sd in sds]}


BAG_EPOCH_NS = 1_700_000_000 * 1_000_000_000  # bag stamps = log time + this


def bag_ns(t: float) -> int:
    return round(t * 1e9) + BAG_EPOCH_NS


def _stamp(typestore, t: float):
    Time = typestore.types["builtin_interfaces/msg/Time"]
    ns = bag_ns(t)
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def write_bag(
    ref,
    path: Path,
    storage: str = "mcap",
    intensity: str | None = "float32",
    organised: bool = False,
    nan_every: int = 0,
    tf: str | None = "odom",
    extra_topic: str | None = None,
    cloud: bool = True,
    frame_ids: tuple[str, ...] = ("velodyne",),
    layout: str | None = None,
) -> Path:
    """A ROS 2 bag written by rosbags: PointCloud2 on ``/points`` in frame ``velodyne``, and tf
    ``<tf> -> base_link`` (dynamic, at each cloud's stamp) with ``base_link -> velodyne`` static.

    Args:
        intensity: ``float32`` (0–1), ``uint16`` (``reflectivity`` field, 0–65535), ``int32``
            (unsupported) or None.
        organised: clouds of height 2 with padded rows.
        nan_every: every n-th point is a NaN return (added after the scan's points' positions).
        tf: the fixed frame, or None for a bag without /tf.
        extra_topic: a second PointCloud2 topic (same clouds).
        cloud: False writes no PointCloud2 topic at all (only /tf).
        frame_ids: the clouds' frames, in turn (cloud k is in ``frame_ids[k % len]``), each with a
            static ``base_link -> frame`` transform (the same calibration).
        layout: a damaged layout of the (unorganised) clouds: ``half_width`` (width covers half the
            data, row_step the whole), ``short_row_step`` (width and row_step half the data),
            ``wide`` (width twice the points, past row_step).
    """
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types
    pc2, pf, hdr = T["sensor_msgs/msg/PointCloud2"], T["sensor_msgs/msg/PointField"], T["std_msgs/msg/Header"]
    tfm, tst = T["tf2_msgs/msg/TFMessage"], T["geometry_msgs/msg/TransformStamped"]
    tr_t, vec, quat = (
        T["geometry_msgs/msg/Transform"],
        T["geometry_msgs/msg/Vector3"],
        T["geometry_msgs/msg/Quaternion"],
    )
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    cal = calib()

    def transform(parent, child, m, t):
        q = matrix_to_quat(m[:3, :3])
        return tst(
            header=hdr(stamp=_stamp(ts, t), frame_id=parent),
            child_frame_id=child,
            transform=tr_t(
                translation=vec(x=m[0, 3], y=m[1, 3], z=m[2, 3]),
                rotation=quat(x=q[1], y=q[2], z=q[3], w=q[0]),
            ),
        )

    with Writer(path, version=9, storage_plugin=plugin) as w:
        topics = (["/points"] + ([extra_topic] if extra_topic else [])) if cloud else []
        conns = [w.add_connection(t, pc2.__msgtype__, typestore=ts) for t in topics]
        c_tf = w.add_connection("/tf", tfm.__msgtype__, typestore=ts) if tf else None
        c_static = w.add_connection("/tf_static", tfm.__msgtype__, typestore=ts) if tf else None
        rows = list(frames_of(ref))
        if tf:
            statics = [transform("base_link", f, cal, rows[0][4]) for f in dict.fromkeys(frame_ids)]
            msg = tfm(transforms=statics)
            w.write(c_static, bag_ns(rows[0][4]) - 1, ts.serialize_cdr(msg, tfm.__msgtype__))
        for k, (_fid, scan, _, pose, t) in enumerate(rows):
            log_ns = bag_ns(t) + 1000
            if tf:
                msg = tfm(transforms=[transform(tf, "base_link", pose @ np.linalg.inv(cal), t)])
                w.write(c_tf, log_ns - 1, ts.serialize_cdr(msg, tfm.__msgtype__))
            fields = [pf(name=n, offset=4 * i, datatype=7, count=1) for i, n in enumerate("xyz")]
            dt = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
            if intensity == "float32":
                fields.append(pf(name="intensity", offset=12, datatype=7, count=1))
                dt.append(("intensity", "<f4"))
            elif intensity == "uint16":
                fields.append(pf(name="reflectivity", offset=12, datatype=4, count=1))
                dt += [("reflectivity", "<u2"), ("pad", "<u2")]
            elif intensity == "int32":  # a type no convention holds
                fields.append(pf(name="intensity", offset=12, datatype=5, count=1))
                dt.append(("intensity", "<i4"))
            else:
                dt.append(("pad", "<f4"))
            n = len(scan)
            arr = np.zeros(n, dtype=dt)
            for i, c in enumerate("xyz"):
                arr[c] = scan[:, i]
            if intensity == "float32":
                arr["intensity"] = scan[:, 3]
            elif intensity == "uint16":
                arr["reflectivity"] = np.round(scan[:, 3].astype(np.float64) * 65535).astype(np.uint16)
            if nan_every:
                nan = np.zeros(n // nan_every, dtype=dt)
                nan["x"] = np.nan
                arr = np.insert(arr, np.arange(1, n // nan_every + 1) * nan_every - 1, nan)
            if organised:  # 2 rows, odd count padded with a NaN point, rows padded by 8 bytes
                if len(arr) % 2:
                    pad = np.zeros(1, dtype=dt)
                    pad["x"] = np.nan
                    arr = np.concatenate([arr, pad])
                height, width = 2, len(arr) // 2
                row = np.frombuffer(arr.tobytes(), np.uint8).reshape(2, -1)
                data = np.concatenate([row, np.zeros((2, 8), np.uint8)], axis=1).reshape(-1)
                row_step = row.shape[1] + 8
            else:
                height, width = 1, len(arr)
                data = np.frombuffer(arr.tobytes(), np.uint8)
                row_step = data.size
                if layout == "half_width":
                    width //= 2
                elif layout == "short_row_step":
                    width //= 2
                    row_step = width * arr.dtype.itemsize
                elif layout == "wide":
                    width *= 2
            msg = pc2(
                header=hdr(stamp=_stamp(ts, t), frame_id=frame_ids[k % len(frame_ids)]),
                height=height,
                width=width,
                fields=fields,
                is_bigendian=False,
                point_step=arr.dtype.itemsize,
                row_step=row_step,
                data=data,
                is_dense=not (nan_every or organised),
            )
            for conn in conns:
                w.write(conn, log_ns, ts.serialize_cdr(msg, pc2.__msgtype__))
    return path
