"""Issue 40's findings on logs and labelling (one test a finding; model folders: test_model_folders.py)."""

from __future__ import annotations

import numpy as np
import pytest

from dsnet_core.errors import ScanFormatError
from dsnet_core.io.folder import FolderReader
from storage.run import RunStore
from tasks.methods import get_pipeline
from tasks.runner import run_stage_plain
from tests.logs import make_log

P = get_pipeline()  # the DS-Net stages


def _folder_log(tmp_path, n_frames: int = 4):
    """A folder log of ``.npy`` scans with KITTI poses, its first scan holding an ``inf`` coordinate."""
    src = make_log(tmp_path / "kitti", ("00",), n_frames=n_frames, n_ground=400, n_car=60)
    folder = tmp_path / "folder"
    folder.mkdir()
    for i in range(n_frames):
        scan = np.fromfile(src / f"sequences/00/velodyne/{i:06d}.bin", np.float32).reshape(-1, 4)
        if i == 0:
            scan[5, 0] = np.inf
        np.save(folder / f"scan{i}.npy", scan)
    (folder / "poses.txt").write_text((src / "sequences/00/poses.txt").read_text())
    return folder


def test_a_bad_first_scan_quarantines_only_its_frame(tmp_path):
    """Finding: with ``--on-error skip`` a first scan with an ``inf`` coordinate quarantined every frame
    (the sequence's intensity convention was decided on that scan alone)."""
    folder = _folder_log(tmp_path)
    reader = FolderReader(folder)
    frames = reader.frames("folder")
    with pytest.raises(ScanFormatError, match=r"scan0\.npy"):
        reader.scan(frames[0])
    assert reader.intensity_convention("folder") == "unit"  # decided on scan1, the first that reads
    assert reader.scan(frames[1]).shape[1] == 4

    store = RunStore(tmp_path / "run")
    run = {"data": str(folder), "format": "folder", "options": {"block_size": 2, "on_error": "skip"}}
    store.write_run_config("r1", run)
    m = run_stage_plain(store, P, "folder", "ingest", run, "r1")
    t = store.read_table("folder", P["ingest"].table("frames")).to_pydict()
    assert t["status"] == ["quarantined", "ok", "ok", "ok"] and m.counts["quarantined"] == 1
    assert "scan0.npy" in t["reason"][0] and t["reason"][1:] == [None, None, None]
    assert all(n > 0 for n in t["n_points"][1:])


def test_no_readable_scan_names_the_first_scans_problem(tmp_path):
    folder = _folder_log(tmp_path, n_frames=2)
    scan = np.load(folder / "scan1.npy")
    scan[0, 1] = np.inf
    np.save(folder / "scan1.npy", scan)
    reader = FolderReader(folder)
    with pytest.raises(ScanFormatError, match=r"scan0\.npy"):
        reader.intensity_convention("folder")
