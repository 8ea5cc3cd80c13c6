"""`dsnet label --estimate-poses` in a real process: a sequence without poses.txt gets KISS-ICP poses,
one with poses keeps the log's; without the flag, 4D align names the flag."""

import shutil
import subprocess

import numpy as np

from dsnet_core.io.semantickitti import SemanticKittiReader
from dsnet_core.temporal.odometry import trajectory_drift
from storage.run import RunStore
from tasks.methods import get_pipeline
from tests.flows.conftest import REPO, cli

P = get_pipeline()  # the DS-Net stages


ARGS = ("--scans", "2", "--until", "align")


def test_label_estimate_poses(synth_log, cli_env, tmp_path):
    log = tmp_path / "log"
    shutil.copytree(synth_log, log)
    for name in ("poses.txt", "calib.txt"):  # sequence 00 loses its poses, 01 keeps them
        (log / "sequences" / "00" / name).unlink()
    root = str(tmp_path / "run")

    def label(*extra):
        return subprocess.run(
            cli("label", str(log), "--run", root, *ARGS, *extra),
            cwd=REPO, env=cli_env, capture_output=True, text=True, timeout=300,
        )  # fmt: skip

    res = label()
    assert res.returncode == 2, res.stdout + res.stderr
    assert "sequence 00: volumes of --scans 2 need poses and the log has none" in res.stderr
    assert res.stderr.count("error:") == 1
    assert "dsnet label --estimate-poses" in res.stderr

    res = label("--estimate-poses")
    assert res.returncode == 0, res.stdout + res.stderr
    store = RunStore(root)
    reader = SemanticKittiReader(synth_log)
    for seq, source in (("00", "estimated"), ("01", "log")):
        assert store.read_manifest(seq, "align").status == "done"
        t = store.read_table(seq, P["ingest"].table("frames")).to_pydict()
        assert t["pose_source"] == [source] * 6
        poses = np.stack([np.reshape(p, (4, 4)) for p in t["pose"]])
        truth = np.stack([reader.pose(f) for f in reader.frames(seq)])
        if source == "log":
            np.testing.assert_allclose(poses, truth, atol=1e-9)
        else:
            drift = trajectory_drift(poses, truth)
            assert drift["max_position_error_m"] < 0.05 * drift["path_m"]  # measured 0.14 m of 5.9 m


def test_serve_pending_follows_the_flag(synth_log, tmp_path):
    from flows.watch import pending_sequences
    from tests.helpers.label_request import req
    from tests.helpers.plain_runner import run_stage_plain

    log = tmp_path / "log"
    shutil.copytree(synth_log, log)
    for name in ("poses.txt", "calib.txt"):
        (log / "sequences" / "00" / name).unlink()
    store = RunStore(tmp_path / "run")
    stages = {"ingest": {"estimate_poses": True}}
    run = {"data": str(log), "stages": req(log, store.uri, None, stages).stage_configs(P)}  # as dsnet label
    store.write_run_config("r1", run)
    for seq in ("00", "01"):
        run_stage_plain(store, P, seq, "ingest", run, "r1")
    assert pending_sequences(req(log, store.uri, None, stages, until="ingest")) == []
    # the flag is part of ingest's fingerprint: a tick without it relabels every sequence
    assert pending_sequences(req(log, store.uri, until="ingest")) == ["00", "01"]
