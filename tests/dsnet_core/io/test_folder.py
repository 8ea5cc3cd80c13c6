"""Folders of scans: every suffix, written by an independent library, reads back as the
SemanticKITTI path reads the same (pre-quantised) log; ordering, trajectories and bad input."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from dsnet_core.errors import (
    DataFormatError,
    IntensityFormatError,
    LabelFormatError,
    PointFileFormatError,
    PoseFormatError,
    SequenceLayoutError,
)
from dsnet_core.io.folder import FolderReader, stem_time
from dsnet_core.io.formats import detect_format, open_log
from dsnet_core.io.pointfiles import bin_columns
from tests.dsnet_core.io import encode
from tests.dsnet_core.io.compare import assert_same_log

CASES = {  # name: (quantum, writer, expected source convention)
    "bin4": ("unit", lambda r, p: encode.write_bin(r, p, labels=True), "unit"),
    "bin5": ("uint8", lambda r, p: encode.write_bin(r, p, columns=5), "uint8"),
    "npy": ("unit", lambda r, p: encode.write_numpy(r, p, "npy"), "unit"),
    "npy-structured": ("unit", lambda r, p: encode.write_numpy(r, p, "structured"), "unit"),
    "npz": ("unit", lambda r, p: encode.write_numpy(r, p, "npz"), "unit"),
    "pcd-ascii": ("ascii", lambda r, p: encode.write_pcd(r, p, "ascii"), "unit"),
    "pcd-binary": ("unit", lambda r, p: encode.write_pcd(r, p, "binary"), "unit"),
    "pcd-binary_compressed": ("unit", lambda r, p: encode.write_pcd(r, p, "binary_compressed"), "unit"),
    "pcd-uint8": ("uint8", lambda r, p: encode.write_pcd(r, p, "binary", "uint8"), "uint8"),
    "ply-binary": ("unit", lambda r, p: encode.write_ply(r, p), "unit"),
    "ply-ascii": ("ascii", lambda r, p: encode.write_ply(r, p, text=True), "unit"),
    "las": ("las", lambda r, p: encode.write_las(r, p, 0.001), "uint16"),
    "laz": ("las", lambda r, p: encode.write_las(r, p, 0.001, laz=True), "uint16"),
}


@pytest.mark.parametrize("case", list(CASES))
def test_each_suffix_reads_as_the_semantickitti_path(case, quantised, tmp_path):
    quantum, write, convention = CASES[case]
    ref = quantised(quantum)
    root = write(ref, tmp_path / "scans")
    assert detect_format(root) == "folder"
    reader = open_log(root)
    assert reader.format == "folder" and reader.sequences() == ["scans"]
    assert reader.intensity_convention("scans") == convention
    assert_same_log(reader, ref, labels=case == "bin4")


def test_tum_trajectory_and_folder_of_sequences(quantised, tmp_path):
    ref = quantised("unit")
    seq = encode.write_bin(ref, tmp_path / "log" / "drive_b")
    (seq / "poses.txt").unlink()
    encode.write_meta(ref, seq, poses="tum", times=True)
    shutil.copytree(seq, tmp_path / "log" / "drive_a")
    reader = FolderReader(tmp_path / "log")
    assert reader.sequences() == ["drive_a", "drive_b"]
    np.testing.assert_allclose(reader.poses("drive_b"), ref.poses("00"), rtol=0, atol=1e-9)
    # without times.txt the TUM rows give poses and times row by row
    (seq / "times.txt").unlink()
    reader = FolderReader(tmp_path / "log")
    np.testing.assert_allclose(reader.poses("drive_b"), ref.poses("00"), rtol=0, atol=1e-9)
    assert [reader.timestamp(f) for f in reader.frames("drive_b")] == pytest.approx(
        [ref.timestamp(f) for f in ref.frames("00")]
    )


def test_tum_is_interpolated_at_scan_times(quantised, tmp_path):
    ref = quantised("unit")
    root = encode.write_bin(ref, tmp_path / "scans")
    t = np.loadtxt(root / "times.txt")
    # two samples bracketing the scans: a straight line at 2 m/s along x, no rotation
    (root / "poses.txt").unlink()
    (root / "poses.tum").write_text(
        f"{t[0] - 1} 0 0 0 0 0 0 1\n{t[-1] + 1} {2 * (t[-1] - t[0] + 2)} 0 0 0 0 0 1\n"
    )
    poses = FolderReader(root).poses("scans")
    np.testing.assert_allclose(poses[:, 0, 3], 2 * (t - t[0] + 1), atol=1e-12)
    (root / "poses.tum").write_text(f"{t[0]} 0 0 0 0 0 0 1\n{t[1]} 1 0 0 0 0 0 1\n")
    with pytest.raises(PoseFormatError, match="not the scan time"):
        FolderReader(root).poses("scans")


def test_natural_and_time_order(tmp_path):
    pts = np.zeros((2, 4), np.float32)
    names = {"scan10": 1700000000.3, "scan2": 1700000000.1, "scan9": 1700000000.2}
    for name in names:
        pts.tofile(tmp_path / f"{name}.bin")
    assert [f.frame_id for f in FolderReader(tmp_path).frames(tmp_path.name)] == ["scan2", "scan9", "scan10"]
    np.savetxt(tmp_path / "times.txt", [3.0, 1.0, 2.0])  # in name order: scan2, scan9, scan10
    reader = FolderReader(tmp_path, order="time")
    assert [f.frame_id for f in reader.frames(tmp_path.name)] == ["scan9", "scan10", "scan2"]
    assert [reader.timestamp(f) for f in reader.frames(tmp_path.name)] == [1.0, 2.0, 3.0]


def test_timestamps_from_file_names(tmp_path):
    assert stem_time("1700000000") == 1700000000.0
    assert stem_time("1700000000123") == pytest.approx(1700000000.123)
    assert stem_time("1700000000123456789") == pytest.approx(1700000000.123456789)
    assert stem_time("000042") is None
    for ns in (1700000000200000000, 1700000000100000000):
        np.zeros((1, 4), np.float32).tofile(tmp_path / f"{ns}.bin")
    reader = FolderReader(tmp_path, order="time")
    assert [reader.timestamp(f) for f in reader.frames(tmp_path.name)] == pytest.approx(
        [1700000000.1, 1700000000.2]
    )


def test_bin_column_rule():
    assert bin_columns([16, 32, 48]) == 4
    assert bin_columns([20, 40, 60]) == 5
    both = np.zeros((4, 5), np.float32)
    both[:, 4] = [0, 1, 31, 2]  # a ring index
    assert bin_columns([80], both.tobytes()) == 5
    both[:, 4] = [0.25, 1, 31, 2]
    assert bin_columns([80], both.tobytes()) == 4


def test_labels_beside_scans_are_checked(quantised, tmp_path):
    ref = quantised("unit")
    root = encode.write_bin(ref, tmp_path / "scans", labels=True)
    frame = FolderReader(root).frames("scans")[0]
    (root / "labels").mkdir()
    shutil.move(root / f"{frame.frame_id}.label", root / "labels" / f"{frame.frame_id}.label")
    reader = FolderReader(root)
    assert reader.frames("scans")[0].label_path == root / "labels" / f"{frame.frame_id}.label"
    np.array([7], np.uint32).tofile(root / "labels" / f"{frame.frame_id}.label")
    with pytest.raises(LabelFormatError, match="has 1 labels but the scan has"):
        FolderReader(root).labels(FolderReader(root).frames("scans")[0])


PCL_EXAMPLE = b"""# .PCD v.7 - Point Cloud Data file format
VERSION .7
FIELDS x y z rgb
SIZE 4 4 4 4
TYPE F F F F
COUNT 1 1 1 1
WIDTH 3
HEIGHT 1
VIEWPOINT 0 0 0 1 0 0 0
POINTS 3
DATA ascii
0.93773 0.33763 0 4.2108e+06
0.90805 0.35641 0 4.2108e+06
0.81915 0.32 0 4.2108e+06
"""


def test_pcl_documentation_example_without_intensity(tmp_path):
    (tmp_path / "a.pcd").write_bytes(PCL_EXAMPLE)  # the example of PCL's PCD format page
    reader = FolderReader(tmp_path)
    assert reader.intensity_convention(tmp_path.name) == "none"
    scan = reader.scan(reader.frames(tmp_path.name)[0])
    assert np.array_equal(
        scan, np.float32([[0.93773, 0.33763, 0, 0], [0.90805, 0.35641, 0, 0], [0.81915, 0.32, 0, 0]])
    )


def _binary_pcd(tmp_path, quantised) -> tuple:
    root = encode.write_pcd(quantised("unit"), tmp_path / "scans", "binary")
    return root, sorted(root.glob("*.pcd"))[0]


def test_truncated_pcd_body(tmp_path, quantised):
    root, path = _binary_pcd(tmp_path, quantised)
    path.write_bytes(path.read_bytes()[:-7])
    reader = FolderReader(root)
    with pytest.raises(PointFileFormatError, match=r"binary body has .* bytes.*truncated") as err:
        reader.scan(reader.frames("scans")[0])
    assert str(err.value).startswith(f"{path}: ") and "\n" not in str(err.value)


def test_truncated_compressed_pcd(tmp_path, quantised):
    root = encode.write_pcd(quantised("unit"), tmp_path / "scans", "binary_compressed")
    path = sorted(root.glob("*.pcd"))[0]
    path.write_bytes(path.read_bytes()[:-100])
    with pytest.raises(PointFileFormatError, match="truncated"):
        FolderReader(root).scan(FolderReader(root).frames("scans")[0])


def test_unknown_pcd_data(tmp_path, quantised):
    root, path = _binary_pcd(tmp_path, quantised)
    path.write_bytes(path.read_bytes().replace(b"DATA binary", b"DATA binary_zstd"))
    with pytest.raises(PointFileFormatError, match="unknown DATA 'binary_zstd'") as err:
        FolderReader(root).scan(FolderReader(root).frames("scans")[0])
    assert str(err.value).startswith(str(path))


@pytest.mark.parametrize("text", [False, True])
def test_ply_without_xyz(tmp_path, text):
    from plyfile import PlyData, PlyElement

    arr = np.zeros(3, dtype=[("u", "<f4"), ("v", "<f4"), ("intensity", "<f4")])
    PlyData([PlyElement.describe(arr, "vertex")], text=text).write(str(tmp_path / "a.ply"))
    with pytest.raises(PointFileFormatError, match=r"no x/y/z field \(fields: u, v, intensity\)") as err:
        FolderReader(tmp_path).scan(FolderReader(tmp_path).frames(tmp_path.name)[0])
    assert str(err.value).startswith(str(tmp_path / "a.ply"))


@pytest.mark.parametrize("kind", ["pcd", "npz"])
def test_intensity_column_of_the_wrong_type(tmp_path, kind):
    xyz = np.arange(12, dtype=np.float32).reshape(4, 3)
    if kind == "pcd":
        from pypcd4 import PointCloud

        cols = [xyz[:, 0], xyz[:, 1], xyz[:, 2], np.arange(4, dtype=np.int32)]
        types = [np.float32, np.float32, np.float32, np.int32]
        PointCloud.from_points(cols, ("x", "y", "z", "intensity"), types).save(tmp_path / "a.pcd")
    else:
        np.savez(tmp_path / "a.npz", x=xyz[:, 0], y=xyz[:, 1], z=xyz[:, 2], intensity=np.array(["hi"] * 4))
    reader = FolderReader(tmp_path)
    with pytest.raises(IntensityFormatError, match="intensity column has type") as err:
        reader.scan(reader.frames(tmp_path.name)[0])
    assert str(err.value).startswith(str(tmp_path / f"a.{kind}"))


def test_stated_convention_that_does_not_fit(quantised, tmp_path):
    root = encode.write_bin(quantised("uint8"), tmp_path / "scans", columns=5)
    reader = FolderReader(root, intensity="unit")
    with pytest.raises(IntensityFormatError, match="outside the unit convention"):
        reader.scan(reader.frames("scans")[0])


def test_layout_errors(tmp_path):
    (tmp_path / "notes.txt").write_text("x")
    with pytest.raises(SequenceLayoutError, match="no scan files"):
        FolderReader(tmp_path)
    np.zeros((1, 4), np.float32).tofile(tmp_path / "a.bin")
    np.save(tmp_path / "b.npy", np.zeros((1, 4), np.float32))
    with pytest.raises(SequenceLayoutError, match=r"several kinds \(1 \.bin, 1 \.npy\)"):
        FolderReader(tmp_path).frames(tmp_path.name)
    assert len(FolderReader(tmp_path, suffix="npy").frames(tmp_path.name)) == 1
    (tmp_path / "c.bin").write_bytes(b"\0" * 17)
    reader = FolderReader(tmp_path, suffix="bin", bin_columns=4)
    with pytest.raises(DataFormatError, match="not a multiple of 16"):
        reader.scan(reader.frames(tmp_path.name)[1])


def test_ascii_ply_truncated_and_with_faces(tmp_path):
    from plyfile import PlyData, PlyElement

    arr = np.zeros(4, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "u1")])
    arr["x"], arr["intensity"] = [1, 2, 3, 4], [0, 10, 20, 255]
    faces = np.array([([0, 1, 2],)], dtype=[("vertex_indices", "i4", (3,))])
    PlyData([PlyElement.describe(arr, "vertex"), PlyElement.describe(faces, "face")], text=True).write(
        str(tmp_path / "a.ply")
    )
    reader = FolderReader(tmp_path)
    assert reader.intensity_convention(tmp_path.name) == "uint8"
    scan = reader.scan(reader.frames(tmp_path.name)[0])
    assert scan[:, 0].tolist() == [1, 2, 3, 4]
    assert scan[:, 3].tolist() == [0, np.float32(10) / np.float32(255), np.float32(20) / np.float32(255), 1]
    text = (tmp_path / "a.ply").read_text().splitlines()
    (tmp_path / "a.ply").write_text("\n".join(text[: text.index("end_header") + 3]) + "\n")
    with pytest.raises(PointFileFormatError, match="header promises 4 × 4: truncated"):
        FolderReader(tmp_path).scan(FolderReader(tmp_path).frames(tmp_path.name)[0])


@pytest.mark.parametrize(("value", "match"), [(np.inf, "NaN or inf"), (1e30, "beyond 10000 m")])
def test_corrupt_coordinates_name_the_scan(tmp_path, value, match):
    pts = np.zeros((3, 4), np.float32)
    pts[1, 2] = value
    np.save(tmp_path / "a.npy", pts)
    with pytest.raises(DataFormatError, match=match) as err:
        FolderReader(tmp_path).scan(FolderReader(tmp_path).frames(tmp_path.name)[0])
    assert str(err.value).startswith(str(tmp_path / "a.npy"))


def test_points_without_a_return_are_dropped_counted_and_their_labels_masked(tmp_path):
    # an organised cloud (PCL's convention): no return = NaN x, y, z; labels hold one per file point
    pts = np.arange(24, dtype=np.float32).reshape(6, 4)
    pts[[1, 4], :3] = np.nan
    np.save(tmp_path / "a.npy", pts)
    label = np.arange(6, dtype=np.uint32) % 2 * 10  # raw ids 0 and 10 (car)
    label.tofile(tmp_path / "a.label")
    reader = FolderReader(tmp_path)
    frame = reader.frames(tmp_path.name)[0]
    scan = reader.scan(frame)
    assert scan[:, 0].tolist() == [0, 8, 12, 20]
    assert reader.dropped_points(frame) == 2
    assert reader.kept_points(frame).tolist() == [True, False, True, True, False, True]
    assert reader.labels(frame).tolist() == [0, 0, 10, 10]
    assert FolderReader(tmp_path).labels(frame).tolist() == [0, 0, 10, 10]  # without the scan read first
