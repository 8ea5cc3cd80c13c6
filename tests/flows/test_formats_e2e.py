"""``dsnet label`` on every input format, end to end through the command line: the same 2-frame log
(pre-quantised to 8-bit intensity) re-encoded as a nuScenes log, a folder of N×5 ``.bin`` scans and
a ROS 2 bag labels exactly as its SemanticKITTI copy does, and ``dsnet export`` writes the labels in
each log's own terms (nuScenes: challenge-class results by sample_data token, compared after the
class mapping). The run records the format, the reader options and per frame the source's
intensity convention and the points outside the model's grid; a nuScenes run is scored against its
own Panoptic nuScenes ground truth, and ``dsnet eval`` on the exported results gives the same numbers."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from dsnet_core.io.formats import open_log
from dsnet_core.io.nuscenes_export import SceneEncoder
from dsnet_core.io.semantickitti import SemanticKittiReader
from dsnet_core.metrics import read_panoptic_npz
from flows.cli import app
from flows.report import read_report_table
from storage.run import RunStore
from tasks.ingest import FRAMES
from tests.dsnet_core.io.encode import bag_ns, quantised_log, write_bag, write_bin, write_nuscenes
from tests.model_helpers import make_checkpoint

FAST_SHIFT = json.dumps({"kind": "dynamic_shift", "n_seeds": 200, "bandwidths": [0.2, 1.8, 3.4]})


@pytest.fixture(scope="module")
def logs(synth_log, tmp_path_factory):
    root = tmp_path_factory.mktemp("formats")
    src = quantised_log(synth_log, root / "kitti", 2, convention="uint8")
    ref = SemanticKittiReader(src)
    write_nuscenes(ref, root / "nusc")
    write_bin(ref, root / "scans" / "drive1", columns=5)  # nuScenes-like .bin: intensity 0-255, ring
    (root / "bags").mkdir()
    write_bag(ref, root / "bags" / "run1", extra_topic="/points_copy")  # two topics: --topic needed
    return {
        "semantickitti": src,
        "nuscenes": root / "nusc",
        "folder": root / "scans",
        "rosbag": root / "bags",
    }


@pytest.fixture(scope="module")
def ckpt(tmp_path_factory):
    return make_checkpoint(tmp_path_factory.mktemp("ckpt") / "ckpt", seed=3)


def _label(log, run, ckpt, *options: str) -> None:
    args = ["label", str(log), "--run", str(run), "--checkpoint", str(ckpt), "--clusterer", FAST_SHIFT]
    res = CliRunner().invoke(app, [*args, *options])
    assert res.exit_code == 0, res.output


def _export(run, out, *options: str) -> str:
    res = CliRunner().invoke(app, ["export", str(run), "--out", str(out), *options])
    assert res.exit_code == 0, res.output
    return res.output


@pytest.fixture(scope="module")
def reference(prefect_api_url, logs, ckpt, tmp_path_factory):
    """The SemanticKITTI path: frame table and exported labels, in frame order."""
    root = tmp_path_factory.mktemp("ref")
    _label(logs["semantickitti"], root / "run", ckpt)
    _export(root / "run", root / "out")
    reader = SemanticKittiReader(logs["semantickitti"])
    labels = [
        np.fromfile(root / "out/sequences/00/predictions" / f"{f.frame_id}.label", dtype=np.uint32)
        for f in reader.frames("00")
    ]
    return labels, RunStore(root / "run").read_table("00", FRAMES).to_pydict()


CASES = [  # format, sequence, --format/--reader-option arguments, source intensity convention
    ("nuscenes", "scene-0001", [], "uint8"),
    ("folder", "drive1", ["--format", "folder"], "uint8"),
    ("rosbag", "run1", ["--reader-option", "topic=/points"], "unit"),
]


@pytest.mark.parametrize(("fmt", "seq", "options", "convention"), CASES, ids=[c[0] for c in CASES])
def test_label_exports_the_semantickitti_labels_in_the_logs_own_terms(
    prefect_api_url, logs, ckpt, reference, tmp_path, fmt, seq, options, convention
):
    want, ref_frames = reference
    run = tmp_path / "run"
    _label(logs[fmt], run, ckpt, *options)
    store = RunStore(run)
    config = store.read_run_config()
    assert config["format"] == fmt
    assert config["reader_options"] == ({"topic": "/points"} if fmt == "rosbag" else {})
    frames = store.read_table(seq, FRAMES).to_pydict()
    assert frames["intensity_convention"] == [convention] * 2
    assert frames["outside_grid"] == ref_frames["outside_grid"] and min(frames["outside_grid"]) > 0
    reader = open_log(logs[fmt], fmt, config["reader_options"])
    ids = [f.frame_id for f in reader.frames(seq)]
    assert frames["frame_id"] == ids

    out = tmp_path / "out"
    printed = _export(run, out)  # the run's own format by default
    if fmt == "nuscenes":
        enc = SceneEncoder(seq, classes="challenge")  # the model's classes -> challenge classes
        for token, label in zip(ids, want, strict=True):
            assert np.array_equal(
                read_panoptic_npz(out / "panoptic/val" / f"{token}_panoptic.npz"), enc.encode(label)
            )
            lidarseg = np.fromfile(out / "lidarseg/val" / f"{token}_lidarseg.bin", dtype=np.uint8)
            assert np.array_equal(
                lidarseg, read_panoptic_npz(out / "panoptic/val" / f"{token}_panoptic.npz") // 1000
            )
        assert json.loads((out / "val/submission.json").read_text())["meta"]["use_lidar"] is True
        _nuscenes_scores_agree(store, logs[fmt], out, tmp_path)
    else:  # one .label per scan file name / message stamp
        assert f"wrote {fmt} labels" in printed
        got = [np.fromfile(out / seq / f"{i}.label", dtype=np.uint32) for i in ids]
        assert all(np.array_equal(a, b) for a, b in zip(got, want, strict=True))
        src = SemanticKittiReader(logs["semantickitti"])
        first = src.frames("00")[0]
        assert ids[0] == (first.frame_id if fmt == "folder" else f"{bag_ns(src.timestamp(first)):019d}")


def _nuscenes_scores_agree(store, log, results, tmp_path) -> None:
    """The run's score stage (through the class mapping) and ``dsnet eval`` of the exported results."""
    row = read_report_table(store, "score_run").to_pylist()[0]
    assert row["scoring"] == "panoptic-nuscenes" and row["class_mapping"].endswith(
        "-to-panoptic-nuscenes.yaml"
    )
    out = tmp_path / "eval.json"
    res = CliRunner().invoke(app, ["eval", "--gt", str(log), "--pred", str(results), "--json", str(out)])
    assert res.exit_code == 0, res.output
    assert "expressible (12)" in res.output
    scores = json.loads(out.read_text())
    for key in ("pq", "sq", "rq", "miou", "lstq", "pat"):
        assert scores["all"][key] == pytest.approx(row[key], abs=1e-12), key
    assert scores["expressible"]["pq"] == pytest.approx(row["pq_expressible"], abs=1e-12)
    assert scores["frames"] == 2


def test_a_scheduled_tick_labels_each_bag_of_a_folder_once(prefect_api_url, logs, ckpt, tmp_path):
    """``dsnet serve --watch`` on a folder of bags: one sequence per bag, the reader options of the
    request (``--reader-option topic=...``) carried through the deployment's parameters."""
    import shutil

    from flows.request import LabelRequest, parse_reader_options, stage_settings
    from flows.watch import auto_label

    watched = tmp_path / "bags"
    for name in ("site-a", "site-b"):
        shutil.copytree(logs["rosbag"] / "run1", watched / name)
    request = LabelRequest(
        data=str(watched),
        root=str(tmp_path / "runs"),
        reader_options=parse_reader_options(["topic=/points_copy"]),
        stages=stage_settings(2, checkpoint=str(ckpt), clusterer=FAST_SHIFT),
    )
    params = request.model_dump(mode="json")  # what the deployment stores
    first = auto_label(params, dataset="bags")
    assert first["labelled"] == ["site-a", "site-b"] and first["failed"] == []
    store = RunStore(tmp_path / "runs")
    assert store.read_run_config()["reader_options"] == {"topic": "/points_copy"}
    assert all(store.read_manifest(s, "stitch").status == "done" for s in ("site-a", "site-b"))
    assert auto_label(params, dataset="bags")["labelled"] == []  # nothing new or stale
