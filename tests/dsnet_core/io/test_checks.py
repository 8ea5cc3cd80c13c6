"""The checks every reader's scans pass (``dsnet_core.io.checks``), and LAS headers whose scale
factors collapse every point onto one: a scan of one repeated point is refused in every format
(it was labelled, every point one class, with exit 0)."""

from __future__ import annotations

import numpy as np
import pytest

from dsnet_core.errors import PointFileFormatError, ScanFormatError
from dsnet_core.io.checks import check_points
from dsnet_core.io.folder import FolderReader
from dsnet_core.io.semantickitti import SemanticKittiReader


def test_check_points_refuses_one_repeated_point_and_nothing_else():
    same = np.tile(np.float32([1.5, -2.0, 0.25, 0.7]), (1000, 1))
    with pytest.raises(
        ScanFormatError,
        match=r"^scan.bin: all 1000 points are the same point \(1.5, -2, 0.25\) m: a degenerate scan",
    ):
        check_points("scan.bin", same)
    check_points("scan.bin", same[:1])  # one point: nothing to compare
    check_points("scan.bin", same[:0])
    varied = same.copy()
    varied[-1, 2] = 0.26  # one point elsewhere is a (tiny) scan
    check_points("scan.bin", varied)
    varied = same.copy()
    varied[:, 3] = np.linspace(0, 1, 1000)  # intensities alone do not make a scan
    with pytest.raises(ScanFormatError, match="all 1000 points are the same point"):
        check_points("scan.bin", varied)


def _write_las(path, scales, xyz_int: np.ndarray) -> None:
    import laspy

    header = laspy.LasHeader(point_format=1, version="1.2")
    header.scales = np.asarray(scales, dtype=np.float64)
    header.offsets = np.array([10.0, 20.0, 1.5])
    las = laspy.LasData(header)
    las.X, las.Y, las.Z = (xyz_int[:, i].astype(np.int32) for i in range(3))
    las.intensity = np.arange(len(xyz_int), dtype=np.uint16)
    las.write(str(path))


@pytest.mark.parametrize("suffix", [".las", ".laz"])
def test_las_scale_factors_of_zero_are_refused(tmp_path, suffix):
    xyz = np.random.default_rng(0).integers(-30000, 30000, (500, 3))
    _write_las(tmp_path / f"a{suffix}", [0.0, 0.0, 0.0], xyz)
    reader = FolderReader(tmp_path)
    with pytest.raises(
        PointFileFormatError, match=r"header scale factors \[0.0, 0.0, 0.0\] and offsets"
    ) as err:
        reader.scan(reader.frames(tmp_path.name)[0])
    assert str(err.value).startswith(f"{tmp_path / f'a{suffix}'}: ") and "\n" not in str(err.value)
    _write_las(tmp_path / f"a{suffix}", [0.001, 0.0, 0.001], xyz)  # one axis is enough
    with pytest.raises(PointFileFormatError, match=r"scale factors \[0.001, 0.0, 0.001\]"):
        FolderReader(tmp_path).scan(reader.frames(tmp_path.name)[0])
    _write_las(tmp_path / f"a{suffix}", [0.001] * 3, xyz)  # the same file with a real scale reads
    scan = FolderReader(tmp_path).scan(reader.frames(tmp_path.name)[0])
    np.testing.assert_allclose(scan[:, :3], xyz * 0.001 + [10.0, 20.0, 1.5], rtol=0, atol=1e-5)


def test_a_las_scan_of_one_repeated_point_is_refused(tmp_path):
    _write_las(tmp_path / "a.las", [0.001] * 3, np.zeros((300, 3), dtype=np.int64))
    with pytest.raises(ScanFormatError, match=r"all 300 points are the same point \(10, 20, 1.5\) m") as err:
        FolderReader(tmp_path).scan(FolderReader(tmp_path).frames(tmp_path.name)[0])
    assert str(err.value).startswith(str(tmp_path / "a.las"))


def test_a_zeroed_kitti_scan_is_refused_naming_it(synth_log, tmp_path):
    import shutil

    root = tmp_path / "log"
    shutil.copytree(synth_log / "sequences" / "00", root / "sequences" / "00")
    reader = SemanticKittiReader(root)
    frame = reader.frames("00")[3]
    np.zeros((reader.scan(frame).shape[0], 4), np.float32).tofile(frame.scan_path)
    with pytest.raises(ScanFormatError, match=r"all \d+ points are the same point \(0, 0, 0\) m") as err:
        reader.scan(frame)
    assert str(err.value).startswith(f"{frame.scan_path}: ")
