"""nuScenes logs: tables as nuscenes-devkit documents them, read back as the SemanticKITTI path
reads the same log (labels after the class mapping); pose composition; bad tables."""

from __future__ import annotations

import json

import numpy as np
import pytest

from dsnet_core.errors import LabelFormatError, TableFormatError
from dsnet_core.io.formats import detect_format, open_log
from dsnet_core.io.nuscenes_export import SceneEncoder
from dsnet_core.io.nuscenes_reader import NuScenesReader
from dsnet_core.io.semantickitti import write_frame, write_sequence_meta
from dsnet_core.synth.log import kitti_tr
from tests.dsnet_core.io import encode
from tests.dsnet_core.io.compare import assert_same_log

WORLD = np.eye(4)
WORLD[:3, 3] = [411.3, 1180.9, 0.0]  # a map origin far from the first pose, as in nuScenes


@pytest.fixture(scope="module")
def log(quantised, tmp_path_factory):
    ref = quantised("uint8")
    root = tmp_path_factory.mktemp("nuscenes")
    tokens = encode.write_nuscenes(ref, root, sweep_every=2)  # frame 1 of 0..2 is a sweep
    return ref, root, tokens


def _keyframe_ref(ref, keep):
    return [f for i, f in enumerate(ref.frames("00")) if keep[i]]


def test_keyframes_points_poses_labels(log):
    ref, root, tokens = log
    assert detect_format(root) == "nuscenes"
    reader = open_log(root)
    assert reader.sequences() == ["scene-0001"] and reader.intensity_convention("scene-0001") == "uint8"
    frames = reader.frames("scene-0001")
    assert [f.frame_id for f in frames] == tokens["keyframes"]
    encoder = SceneEncoder("scene-0001")
    for got, want in zip(frames, _keyframe_ref(ref, [True, False, True]), strict=True):
        assert np.array_equal(reader.scan(got), ref.scan(want))
        np.testing.assert_allclose(reader.pose(got), ref.pose(want), rtol=0, atol=1e-9)
        assert reader.timestamp(got) == pytest.approx(ref.timestamp(want), abs=1e-6)
        label = reader.labels(got)
        assert np.array_equal((label & 0xFFFF) * 1000 + (label >> 16), encoder.encode(ref.labels(want)))
    assert reader.label_map.name == "panoptic-nuscenes"


def test_sweeps_on_request(log):
    ref, root, tokens = log
    reader = NuScenesReader(root, sweeps=True)
    frames = reader.frames("scene-0001")
    assert [f.frame_id for f in frames] == tokens["all"]
    assert frames[1].label_path is None and reader.labels(frames[1]) is None
    assert_same_log(reader, ref)


def test_pose_is_ego_pose_after_calibrated_sensor(quantised, tmp_path):
    """A static object seen from a moving ego through a non-identity calibrated_sensor stays put."""
    rng = np.random.default_rng(3)
    obj = np.array([6.0, 2.5, 0.4]) + rng.uniform(-0.6, 0.6, (40, 3))  # world points, metres
    seq = tmp_path / "skitti" / "sequences" / "00"
    poses = []
    for i in range(4):  # 2 m per frame along x with a turning yaw
        yaw = 0.15 * i
        p = np.eye(4)
        p[:3, :3] = [[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]]
        p[:3, 3] = [2.0 * i, 0.3 * i * i, 0.0]
        poses.append(p)
        local = (np.linalg.inv(p) @ np.c_[obj, np.ones(len(obj))].T).T[:, :3]
        write_frame(seq, f"{i:06d}", np.c_[local, np.zeros(len(obj))].astype(np.float32), None)
    write_sequence_meta(seq, np.array(poses), kitti_tr(), np.arange(4) * 0.5)
    from dsnet_core.io.semantickitti import SemanticKittiReader

    root = tmp_path / "nus"
    encode.write_nuscenes(SemanticKittiReader(tmp_path / "skitti"), root, world=WORLD)
    reader = NuScenesReader(root)
    seen = []
    for f in reader.frames("scene-0001"):
        pts = reader.scan(f)[:, :3].astype(np.float64)
        seen.append((reader.pose(f) @ np.c_[pts, np.ones(len(pts))].T).T[:, :3])
    for world in seen:
        assert np.abs(world - seen[0]).max() < 1e-6
        assert np.abs(world - (WORLD[:3, :3] @ obj.T).T - WORLD[:3, 3]).max() < 1e-6
    # the other order (ego_pose applied in the sensor frame) would not hold the object still
    from dsnet_core.io.geometry import pose_matrix

    wrong = []
    for f in reader.frames("scene-0001"):
        sd = reader._sd[f.frame_id]
        ego, cal = reader._ego[sd["ego_pose_token"]], reader._calib[sd["calibrated_sensor_token"]]
        m = pose_matrix(cal["translation"], cal["rotation"]) @ pose_matrix(
            ego["translation"], ego["rotation"]
        )
        pts = reader.scan(f)[:, :3].astype(np.float64)
        wrong.append((m @ np.c_[pts, np.ones(len(pts))].T).T[:, :3])
    assert np.abs(wrong[-1] - wrong[0]).max() > 0.5


def test_pose_matches_the_devkit_composition(log):
    try:
        from tests.dsnet_core.io.devkit_peer import transform_matrix
    except ImportError:  # pragma: no cover - without the peer
        pytest.skip("peer missing: .venv/bin/pip install --no-deps nuscenes-devkit==1.2.0 pyquaternion")
    from pyquaternion import Quaternion

    _, root, _ = log
    reader = NuScenesReader(root)
    for f in reader.frames("scene-0001"):
        sd = reader._sd[f.frame_id]
        ego, cal = reader._ego[sd["ego_pose_token"]], reader._calib[sd["calibrated_sensor_token"]]
        # as the devkit's tutorials map LiDAR points to the global frame
        devkit = transform_matrix(ego["translation"], Quaternion(ego["rotation"])) @ transform_matrix(
            cal["translation"], Quaternion(cal["rotation"])
        )
        np.testing.assert_allclose(reader.pose(f), devkit, rtol=0, atol=1e-12)


def test_lidarseg_when_no_panoptic(log, tmp_path):
    import shutil

    _, src, tokens = log
    root = tmp_path / "nus"
    shutil.copytree(src, root)
    (root / "v1.0-mini" / "panoptic.json").unlink()
    records = []
    for token in tokens["keyframes"]:
        pan = np.load(root / "panoptic" / "v1.0-mini" / f"{token}_panoptic.npz")["data"]
        name = f"lidarseg/v1.0-mini/{token}_lidarseg.bin"
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        (pan // 1000).astype(np.uint8).tofile(root / name)
        records.append({"token": token, "sample_data_token": token, "filename": name})
    (root / "v1.0-mini" / "lidarseg.json").write_text(json.dumps(records))
    reader = NuScenesReader(root)
    f = reader.frames("scene-0001")[0]
    label = reader.labels(f)
    pan = np.load(src / "panoptic" / "v1.0-mini" / f"{f.frame_id}_panoptic.npz")["data"]
    assert np.array_equal(label, pan // 1000)


def test_table_pointing_at_a_missing_file(log, tmp_path):
    import shutil

    _, src, _ = log
    root = tmp_path / "nus"
    shutil.copytree(src, root)
    reader = NuScenesReader(root)
    frame = reader.frames("scene-0001")[1]
    frame.scan_path.unlink()
    with pytest.raises(TableFormatError, match=r"listed by v1.0-mini's tables for sample_data") as err:
        reader.scan(frame)
    assert str(err.value).startswith(str(frame.scan_path)) and "\n" not in str(err.value)
    frame.label_path.unlink()
    with pytest.raises(TableFormatError, match="file is missing"):
        reader.labels(frame)


def test_bad_tables(log, tmp_path):
    import shutil

    _, src, _ = log
    root = tmp_path / "nus"
    shutil.copytree(src, root)
    shutil.copytree(root / "v1.0-mini", root / "v1.0-trainval")
    with pytest.raises(TableFormatError, match=r"found v1.0-mini, v1.0-trainval; choose one with version="):
        NuScenesReader(root)
    assert NuScenesReader(root, version="v1.0-trainval").sequences() == ["scene-0001"]
    shutil.rmtree(root / "v1.0-trainval")
    cat = root / "v1.0-mini" / "category.json"
    records = json.loads(cat.read_text())
    records[17]["name"] = "vehicle.tank"
    cat.write_text(json.dumps(records))
    with pytest.raises(TableFormatError, match=r"category index 17 is 'vehicle.tank'"):
        NuScenesReader(root)
    (root / "v1.0-mini" / "ego_pose.json").unlink()
    with pytest.raises(TableFormatError, match=r"ego_pose.json: table is missing"):
        NuScenesReader(root)


def test_panoptic_with_the_wrong_length(log, tmp_path):
    import shutil

    _, src, _ = log
    root = tmp_path / "nus"
    shutil.copytree(src, root)
    reader = NuScenesReader(root)
    frame = reader.frames("scene-0001")[0]
    np.savez_compressed(frame.label_path, data=np.zeros(5, np.uint16))
    with pytest.raises(LabelFormatError, match="has 5 labels but the scan has"):
        reader.labels(frame)
