"""``dsnet synth`` and ``dsnet demo`` as a user runs them (real subprocesses, real files)."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from dsnet_core.checkpoints import bundled_checkpoint
from dsnet_core.io import kitti
from dsnet_core.io.semantickitti import SemanticKittiReader
from dsnet_core.synth import kitti_tr

ROOT = Path(__file__).resolve().parents[2]


def dsnet(*args: str, cwd: Path = ROOT, env: dict | None = None, timeout: int = 300):
    """Run ``dsnet ARGS`` from this checkout (``env``: e.g. the session Prefect server's)."""
    env = env if env is not None else {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run(
        [sys.executable, "-m", "flows.cli", *args],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def test_synth_two_sequences_load_back(tmp_path):
    out = tmp_path / "log"
    res = dsnet("synth", str(out), "--sequences", "2", "--frames", "10", "--seed", "0")
    assert res.returncode == 0, res.stderr
    assert f"wrote 2 sequence(s) × 10 frames (hdl64) to {out / 'sequences'}" in res.stdout
    reader = SemanticKittiReader(out)
    assert reader.sequences() == ["00", "01"]
    for seq in reader.sequences():
        frames = reader.frames(seq)
        assert [f.frame_id for f in frames] == [f"{i:06d}" for i in range(10)]
        poses = reader.poses(seq)
        assert poses.shape == (10, 4, 4)
        np.testing.assert_allclose(poses[0], np.eye(4), atol=1e-9)
        step = np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1)
        assert ((step > 0.5) & (step < 1.5)).all(), "≈ 5–15 m/s at 10 Hz"
        cam = kitti.read_poses(reader.seq_dir(seq) / "poses.txt")
        assert not np.allclose(cam, poses), "poses.txt is in the camera frame"
        np.testing.assert_allclose(kitti.read_calib(reader.seq_dir(seq) / "calib.txt"), kitti_tr(), atol=1e-9)
        assert [reader.timestamp(f) for f in frames] == pytest.approx([0.1 * i for i in range(10)])
        for f in frames:
            scan = reader.scan(f)
            label = reader.labels(f)
            assert label.shape == (scan.shape[0],) and 100_000 <= scan.shape[0] <= 130_000


def test_synth_refuses_existing_and_unknown_sensor(tmp_path):
    (tmp_path / "sequences" / "00").mkdir(parents=True)
    (tmp_path / "sequences" / "00" / "poses.txt").write_text("")
    res = dsnet("synth", str(tmp_path), "--frames", "1", "--sensor", "vlp32")
    assert res.returncode == 2 and "sequences/00: already holds a sequence" in res.stderr
    res = dsnet("synth", str(tmp_path / "x"), "--sensor", "hdl32")
    assert res.returncode == 2 and "unknown LiDAR model 'hdl32'" in res.stderr


def test_demo_labels_with_the_bundled_models(tmp_path, cli_env):
    out = tmp_path / "demo"

    def demo(*args: str) -> subprocess.CompletedProcess:
        return dsnet("demo", "--out", str(out), "--sensor", "vlp32", *args, env=cli_env, timeout=600)

    res = demo("--frames", "2")
    assert res.returncode == 0, res.stderr
    assert "class histogram" in res.stdout and "motorcyclist" in res.stdout
    assert f"model: bundled model {bundled_checkpoint(2)}" in res.stdout and "tiny-v2-4d" in res.stdout
    assert "records no training" not in res.stdout
    scores = json.loads((out / "scores.json").read_text())
    assert scores["frames"] == 2
    assert f"PQ {100 * scores['pq']:.1f}  LSTQ {100 * scores['lstq']:.1f}" in res.stdout
    assert f"dashboard {out.resolve() / 'run' / 'dashboard.html'}" in res.stdout
    assert (out / "run" / "dashboard.html").stat().st_size > 10_000
    assert len(list((out / "predictions/sequences/00/predictions").glob("*.label"))) == 2
    # a second run replaces its own log; k = 1 takes the single-scan model
    res = demo("--frames", "1", "--scans", "1")
    assert res.returncode == 0, res.stderr
    assert f"model: bundled model {bundled_checkpoint(1)}" in res.stdout
    assert len(SemanticKittiReader(out / "log").frames("00")) == 1
    assert json.loads((out / "scores.json").read_text())["frames"] == 1


@pytest.mark.slow
def test_demo_labels_exports_and_scores_with_a_checkpoint(tmp_path, cli_env):
    from tests.model_helpers import make_checkpoint

    ckpt = make_checkpoint(tmp_path / "ckpt")
    out = tmp_path / "demo"
    args = ("demo", "--out", str(out), "--frames", "3", "--sensor", "vlp32", "--checkpoint", str(ckpt))
    res = dsnet(*args, env=cli_env, timeout=600)
    assert res.returncode == 0, res.stderr
    assert "records no training" in res.stdout  # a random-weight checkpoint is not passed off as a model
    assert "PQ† and LSTQ" in res.stdout and f"scores {out / 'scores.json'}" in res.stdout
    assert len(list((out / "predictions/sequences/00/predictions").glob("*.label"))) == 3
    assert json.loads((out / "scores.json").read_text())["frames"] == 3


def test_synth_style_and_sensor_are_recorded(tmp_path):
    out = tmp_path / "log"
    res = dsnet("synth", str(out), "--frames", "1", "--style", "country", "--sensor", "vlp16")
    assert res.returncode == 0, res.stderr
    assert "(country street, vlp16)" in res.stdout
    record = json.loads((out / "sequences/00/synth.json").read_text())
    assert (record["style"], record["sensor"], record["beams"]) == ("country", "vlp16", 16)
    res = dsnet("synth", str(tmp_path / "x"), "--style", "suburb")
    assert res.returncode == 2 and "unknown street style 'suburb'" in res.stderr


def test_synth_variety_is_said_recorded_and_checked(tmp_path):
    out = tmp_path / "log"
    res = dsnet(
        "synth", str(out), "--frames", "1", "--style", "residential", "--sensor", "vlp16", "--variety", "wide"
    )
    assert res.returncode == 0, res.stderr
    assert "(residential street, vlp16, wide variety)" in res.stdout
    assert json.loads((out / "sequences/00/synth.json").read_text())["variety"] == "wide"
    res = dsnet("synth", str(tmp_path / "x"), "--variety", "narrow")
    assert res.returncode == 2 and "unknown synth variety 'narrow'; choose base or wide" in res.stderr
