"""SemanticKITTI readers/writers: round trips and every bad-input case of the issue."""

import numpy as np
import pytest

from dsnet_core.errors import LabelFormatError, PoseFormatError, ScanFormatError, SequenceLayoutError
from dsnet_core.io import kitti
from dsnet_core.io.semantickitti import SemanticKittiReader, write_frame, write_sequence_meta


def _yaw(t: float, x: float) -> np.ndarray:
    m = np.eye(4)
    c, s = np.cos(t), np.sin(t)
    m[:2, :2] = [[c, -s], [s, c]]
    m[0, 3] = x
    return m


TR = np.array([[0, -1, 0, 0.1], [0, 0, -1, -0.05], [1, 0, 0, -0.3], [0, 0, 0, 1]], dtype=np.float64)


def make_log(root, n_frames=3, n_points=100, poses=True, labels=True, seq="00"):
    rng = np.random.default_rng(0)
    seq_dir = root / "sequences" / seq
    for i in range(n_frames):
        scan = rng.normal(size=(n_points, 4)).astype(np.float32)
        label = kitti.join_label(rng.choice([10, 40, 50, 252], n_points), rng.integers(0, 3, n_points))
        write_frame(seq_dir, f"{i:06d}", scan, label if labels else None)
    if poses:
        lidar = np.stack([_yaw(0.1 * i, 2.0 * i) for i in range(n_frames)])
        write_sequence_meta(seq_dir, lidar, TR, np.arange(n_frames) * 0.1)
    return seq_dir


def test_round_trip(tmp_path):
    seq_dir = make_log(tmp_path)
    reader = SemanticKittiReader(tmp_path)
    assert reader.sequences() == ["00"]
    frames = reader.frames("00")
    assert [f.frame_id for f in frames] == ["000000", "000001", "000002"]
    scan = reader.scan(frames[1])
    assert scan.shape == (100, 4) and scan.dtype == np.float32
    label = reader.labels(frames[1])
    assert label.dtype == np.uint32 and label.shape == (100,)
    sem, inst = kitti.split_label(label)
    assert set(np.unique(sem)) <= {10, 40, 50, 252}
    assert (kitti.join_label(sem, inst) == label).all()
    # LiDAR-frame poses survive the camera-frame round trip through Tr
    np.testing.assert_allclose(reader.pose(frames[2]), _yaw(0.2, 4.0), atol=1e-9)
    cam = kitti.read_poses(seq_dir / "poses.txt")
    np.testing.assert_allclose(cam[2], TR @ _yaw(0.2, 4.0) @ np.linalg.inv(TR), atol=1e-9)
    assert reader.timestamp(frames[2]) == pytest.approx(0.2)


def test_log_without_poses_or_labels(tmp_path):
    make_log(tmp_path, poses=False, labels=False)
    reader = SemanticKittiReader(tmp_path)
    ref = reader.frames("00")[0]
    assert reader.pose(ref) is None and reader.labels(ref) is None and reader.timestamp(ref) is None


def test_truncated_scan(tmp_path):
    seq_dir = make_log(tmp_path)
    f = seq_dir / "velodyne" / "000001.bin"
    f.write_bytes(f.read_bytes()[:-6])
    reader = SemanticKittiReader(tmp_path)
    with pytest.raises(ScanFormatError, match=r"000001\.bin: size \d+ bytes is not a multiple of 16"):
        reader.scan(reader.frames("00")[1])


def test_nan_scan(tmp_path):
    seq_dir = make_log(tmp_path)
    f = seq_dir / "velodyne" / "000000.bin"
    scan = kitti.read_scan(f)
    scan[3, 1] = np.nan
    scan[7, 0] = np.inf
    kitti.write_scan(f, scan)
    with pytest.raises(ScanFormatError, match=r"000000\.bin: 2 points have NaN or inf"):
        kitti.read_scan(f)


def test_far_points_name_the_scan(tmp_path):
    seq_dir = make_log(tmp_path)
    f = seq_dir / "velodyne" / "000001.bin"
    scan = kitti.read_scan(f)
    scan[4, 2] = 1e30
    kitti.write_scan(f, scan)
    reader = SemanticKittiReader(tmp_path)
    with pytest.raises(ScanFormatError, match=r"000001\.bin: 1 points lie beyond 10000 m .*point 4"):
        reader.scan(reader.frames("00")[1])


def test_label_length_mismatch(tmp_path):
    seq_dir = make_log(tmp_path)
    f = seq_dir / "labels" / "000002.label"
    kitti.write_label(f, np.zeros(99, dtype=np.uint32))
    reader = SemanticKittiReader(tmp_path)
    with pytest.raises(LabelFormatError, match=r"000002\.label: has 99 labels but the scan has 100 points"):
        reader.labels(reader.frames("00")[2])


def test_unknown_raw_semantic_id(tmp_path):
    seq_dir = make_log(tmp_path)
    f = seq_dir / "labels" / "000000.label"
    label = kitti.read_label(f)
    label[5] = kitti.join_label(np.array([12]), np.array([0]))[0]
    label[6] = 400
    kitti.write_label(f, label)
    reader = SemanticKittiReader(tmp_path)
    with pytest.raises(LabelFormatError, match=r"000000\.label: raw semantic ids \[12, 400\] are not in"):
        reader.labels(reader.frames("00")[0])


def test_short_poses(tmp_path):
    seq_dir = make_log(tmp_path)
    lines = (seq_dir / "poses.txt").read_text().splitlines()
    (seq_dir / "poses.txt").write_text("\n".join(lines[:2]) + "\n")
    reader = SemanticKittiReader(tmp_path)
    frames = reader.frames("00")
    np.testing.assert_allclose(reader.pose(frames[1]), _yaw(0.1, 2.0), atol=1e-9)  # rows 0, 1 are there
    with pytest.raises(PoseFormatError, match=r"00/poses\.txt: no pose for frame 000002 .*it has 2 rows"):
        reader.pose(frames[2])
    with pytest.raises(PoseFormatError, match=r"00/poses\.txt: no pose for frame 000002"):
        reader.poses("00")
    with pytest.raises(PoseFormatError, match=r"poses\.txt: has 2 poses but the sequence has 3 frames"):
        kitti.read_poses(seq_dir / "poses.txt", n_frames=3)


def test_gap_in_scan_numbering_pairs_poses_by_frame_number(tmp_path):
    """Scan 000001 missing: frame 000002 gets row 2 of poses.txt and times.txt, not row 1."""
    seq_dir = make_log(tmp_path, n_frames=4)
    (seq_dir / "velodyne" / "000001.bin").unlink()
    (seq_dir / "labels" / "000001.label").unlink()
    reader = SemanticKittiReader(tmp_path)
    frames = reader.frames("00")
    assert [(f.frame_id, f.index) for f in frames] == [("000000", 0), ("000002", 1), ("000003", 2)]
    np.testing.assert_allclose(reader.pose(frames[1]), _yaw(0.2, 4.0), atol=1e-9)
    np.testing.assert_allclose(reader.poses("00")[2], _yaw(0.3, 6.0), atol=1e-9)
    assert reader.timestamp(frames[1]) == pytest.approx(0.2)


def test_blank_line_in_poses_does_not_shift_later_rows(tmp_path):
    seq_dir = make_log(tmp_path, n_frames=4)
    lines = (seq_dir / "poses.txt").read_text().splitlines()
    lines[1] = ""  # frame 1 loses its pose; frames 2 and 3 keep theirs
    (seq_dir / "poses.txt").write_text("\n".join(lines) + "\n\n\n")  # trailing blank lines are fine
    reader = SemanticKittiReader(tmp_path)
    frames = reader.frames("00")
    np.testing.assert_allclose(reader.pose(frames[2]), _yaw(0.2, 4.0), atol=1e-9)
    np.testing.assert_allclose(reader.pose(frames[3]), _yaw(0.3, 6.0), atol=1e-9)
    with pytest.raises(PoseFormatError, match=r"00/poses\.txt: no pose for frame 000001 .*line 2 is blank"):
        reader.pose(frames[1])
    with pytest.raises(PoseFormatError, match=r"poses\.txt: line 2 is blank"):
        kitti.read_poses(seq_dir / "poses.txt")
    # the same blank line where the scan is missing is harmless
    (seq_dir / "velodyne" / "000001.bin").unlink()
    reader = SemanticKittiReader(tmp_path)
    assert reader.poses("00").shape == (3, 4, 4)


def test_blank_line_in_times(tmp_path):
    seq_dir = make_log(tmp_path, n_frames=3)
    (seq_dir / "times.txt").write_text("0.0\n\n0.2\n")
    reader = SemanticKittiReader(tmp_path)
    frames = reader.frames("00")
    assert reader.timestamp(frames[2]) == pytest.approx(0.2)
    with pytest.raises(PoseFormatError, match=r"times\.txt: no timestamp for frame 000001 .*line 2 is blank"):
        reader.timestamp(frames[1])


@pytest.mark.parametrize(
    "name, kind, message",
    [
        ("000001 (copy).bin", "file", r"velodyne/000001 \(copy\)\.bin: not a scan name"),
        ("000004.bin", "dir", r"velodyne/000004\.bin: is not a regular file"),
        ("1.bin", "file", r"velodyne/1\.bin: frame number 1 is also 000001\.bin"),
    ],
)
def test_stray_entries_in_velodyne_are_named(tmp_path, name, kind, message):
    seq_dir = make_log(tmp_path)
    stray = seq_dir / "velodyne" / name
    stray.mkdir() if kind == "dir" else stray.write_bytes((seq_dir / "velodyne" / "000001.bin").read_bytes())
    reader = SemanticKittiReader(tmp_path)
    with pytest.raises(SequenceLayoutError, match=message):
        reader.frames("00")


def test_hidden_and_other_files_in_velodyne_are_ignored(tmp_path):
    seq_dir = make_log(tmp_path)
    (seq_dir / "velodyne" / "._000001.bin").write_bytes(b"\x00\x05\x16\x07" * 3)  # macOS AppleDouble
    (seq_dir / "velodyne" / "README.txt").write_text("scans\n")
    reader = SemanticKittiReader(tmp_path)
    assert [f.frame_id for f in reader.frames("00")] == ["000000", "000001", "000002"]
    assert reader.poses("00").shape == (3, 4, 4)


def test_non_rigid_pose(tmp_path):
    seq_dir = make_log(tmp_path)
    lines = (seq_dir / "poses.txt").read_text().splitlines()
    vals = [float(v) for v in lines[1].split()]
    vals[0] *= 1.5  # scale the rotation
    lines[1] = " ".join(str(v) for v in vals)
    (seq_dir / "poses.txt").write_text("\n".join(lines) + "\n")
    reader = SemanticKittiReader(tmp_path)
    with pytest.raises(PoseFormatError, match=r"poses\.txt: row 2 is not a rigid transform"):
        reader.poses("00")


def test_missing_calib_with_poses(tmp_path):
    seq_dir = make_log(tmp_path)
    (seq_dir / "calib.txt").unlink()
    reader = SemanticKittiReader(tmp_path)
    with pytest.raises(PoseFormatError, match=r"calib\.txt: calib\.txt is missing"):
        reader.pose(reader.frames("00")[0])


def test_empty_sequence_folder(tmp_path):
    (tmp_path / "sequences" / "05" / "velodyne").mkdir(parents=True)
    reader = SemanticKittiReader(tmp_path)
    with pytest.raises(SequenceLayoutError, match=r"05/velodyne: sequence has no scans"):
        reader.frames("05")


def test_missing_sequences_root(tmp_path):
    with pytest.raises(SequenceLayoutError, match=r"no 'sequences/' folder"):
        SemanticKittiReader(tmp_path)


def test_path_outside_root(tmp_path):
    root = tmp_path / "data"
    make_log(root)
    outside = tmp_path / "elsewhere"
    make_log(outside, seq="09")
    # a symlinked sequence escaping the root, and a '..' sequence name
    (root / "sequences" / "09").symlink_to(outside / "sequences" / "09")
    reader = SemanticKittiReader(root)
    with pytest.raises(SequenceLayoutError, match="outside the dataset root"):
        reader.frames("09")
    with pytest.raises(SequenceLayoutError, match="outside the dataset root"):
        reader.frames("../../elsewhere/sequences/09")
