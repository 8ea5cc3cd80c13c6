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
from tests.dsnet_core.io.encode import (
    bag_ns,
    frames_of,
    quantised_log,
    write_bag,
    write_bin,
    write_meta,
    write_nuscenes,
    write_ply,
)
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
    (root / "organised").mkdir()
    write_bag(ref, root / "organised" / "run1", organised=True, nan_every=7)  # NaN returns in the grid
    write_organised_pcd(ref, root / "pcd" / "drive1", every=5)
    write_ply(ref, root / "ply" / "drive1")
    return {
        "semantickitti": src,
        "nuscenes": root / "nusc",
        "folder": root / "scans",
        "rosbag": root / "bags",
        "pcd": root / "pcd",
        "ply": root / "ply",
        "organised": root / "organised",
    }


def no_return_mask(n: int, every: int, pad_even: bool = False) -> np.ndarray:
    """Where a NaN return sits after inserting one after every ``every - 1`` of ``n`` points (the
    writers' rule), plus a NaN pad making the count even for a 2-row organised cloud."""
    idx = np.arange(1, n // every + 1) * every - 1
    m = n + len(idx)
    keep = np.ones(m + (m % 2 if pad_even else 0), dtype=bool)
    keep[idx + np.arange(len(idx))] = False
    keep[m:] = False
    return keep


def write_organised_pcd(ref, out, every: int):
    """Binary PCDs written by pypcd4 with a NaN point (PCL's no return) after every ``every - 1``."""
    from pypcd4 import Encoding, PointCloud

    out.mkdir(parents=True)
    for fid, scan, _, _, _ in frames_of(ref):
        keep = no_return_mask(len(scan), every)
        full = np.full((len(keep), 4), np.nan, dtype=np.float32)
        full[keep] = scan
        full[~keep, 3] = 0
        cols = [full[:, 0], full[:, 1], full[:, 2], np.round(full[:, 3] * 255).astype(np.uint8)]
        pc = PointCloud.from_points(cols, ("x", "y", "z", "intensity"), [np.float32] * 3 + [np.uint8])
        pc.save(out / f"{fid}.pcd", encoding=Encoding("binary"))
    write_meta(ref, out)


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


CASES = [  # log, format, sequence, --format/--reader-option arguments, source intensity convention
    ("nuscenes", "nuscenes", "scene-0001", [], "uint8"),
    ("folder", "folder", "drive1", ["--format", "folder"], "uint8"),
    ("rosbag", "rosbag", "run1", ["--topic", "/points"], "unit"),
    ("pcd", "folder", "drive1", [], "uint8"),  # organised: NaN returns dropped, put back on export
    ("ply", "folder", "drive1", [], "unit"),
    ("organised", "rosbag", "run1", [], "unit"),  # 2-row clouds with NaN returns
]
NO_RETURN = {"pcd": (5, False), "organised": (7, True)}  # every n-th point, padded to an even count


@pytest.mark.parametrize(("log", "fmt", "seq", "options", "convention"), CASES, ids=[c[0] for c in CASES])
def test_label_exports_the_semantickitti_labels_in_the_logs_own_terms(
    prefect_api_url, logs, ckpt, reference, tmp_path, log, fmt, seq, options, convention
):
    want, ref_frames = reference
    run = tmp_path / "run"
    _label(logs[log], run, ckpt, *options)
    store = RunStore(run)
    config = store.read_run_config()
    assert config["format"] == fmt
    assert config["reader_options"] == ({"topic": "/points"} if "--topic" in options else {})
    frames = store.read_table(seq, FRAMES).to_pydict()
    assert frames["intensity_convention"] == [convention] * 2
    masks = [np.ones(len(w), bool) for w in want]
    if log in NO_RETURN:  # the labels of the points with a return, 0 where the source had none
        masks = [no_return_mask(len(w), *NO_RETURN[log]) for w in want]
        want = [np.zeros(len(k), np.uint32) for k in masks]
        for full, k, w in zip(want, masks, reference[0], strict=True):
            full[k] = w
    assert frames["no_return"] == [int((~k).sum()) for k in masks]
    assert frames["outside_grid"] == ref_frames["outside_grid"] and min(frames["outside_grid"]) > 0
    reader = open_log(logs[log], fmt, config["reader_options"])
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
        _nuscenes_scores_agree(store, logs[log], out, tmp_path)
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

    from flows.request import LabelRequest, parse_reader_options
    from flows.watch import auto_label
    from tasks.methods import stage_configs

    watched = tmp_path / "bags"
    for name in ("site-a", "site-b"):
        shutil.copytree(logs["rosbag"] / "run1", watched / name)
    request = LabelRequest(
        data=str(watched),
        root=str(tmp_path / "runs"),
        reader_options=parse_reader_options(["topic=/points_copy"]),
        stages=stage_configs(scans=2, checkpoint=str(ckpt), clusterer=FAST_SHIFT),
    )
    params = request.model_dump(mode="json")  # what the deployment stores
    first = auto_label(params, dataset="bags")
    assert first["labelled"] == ["site-a", "site-b"] and first["failed"] == []
    store = RunStore(tmp_path / "runs")
    assert store.read_run_config()["reader_options"] == {"topic": "/points_copy"}
    assert all(store.read_manifest(s, "stitch").status == "done" for s in ("site-a", "site-b"))
    assert auto_label(params, dataset="bags")["labelled"] == []  # nothing new or stale


DESCRIBED = [  # log, arguments, what the sequences table says
    ("nuscenes", [], ["format: nuscenes", "scene-0001", "uint8", "ego_pose ∘ calibrated_sensor"]),
    ("folder", [], ["format: folder", "drive1", "(.bin", "poses.txt (KITTI 3×4)"]),
    ("pcd", [], ["format: folder", "x y z intensity (.pcd)", "10400"]),  # 5200 NaN returns per scan
    ("rosbag", ["--topic", "/points_copy"], ["format: rosbag", "PointCloud2 /points_copy", "tf odom"]),
    ("organised", [], ["format: rosbag", "PointCloud2 /points", "7430"]),
]


@pytest.mark.parametrize(("log", "options", "want"), DESCRIBED, ids=[d[0] for d in DESCRIBED])
def test_describe_prints_format_fields_intensity_no_returns_and_poses(logs, log, options, want):
    res = CliRunner().invoke(app, ["describe", str(logs[log]), *options], env={"COLUMNS": "240"})
    assert res.exit_code == 0, res.output
    for text in want:
        assert text in res.output, (text, res.output)


def test_a_bag_with_several_cloud_topics_names_them_and_the_option(logs):
    res = CliRunner().invoke(app, ["describe", str(logs["rosbag"])])
    assert res.exit_code == 2
    assert "/points, /points_copy" in res.output and "--topic" in res.output
    res = CliRunner().invoke(
        app, ["describe", str(logs["rosbag"]), "--topic", "/a", "--reader-option", "topic=/b"]
    )
    assert res.exit_code == 2 and "given twice" in res.output


@pytest.mark.parametrize("log", ["nuscenes", "folder"])
def test_a_scheduled_tick_labels_each_scene_or_scan_folder_once(prefect_api_url, logs, ckpt, tmp_path, log):
    """``dsnet serve --watch`` on a nuScenes log (one sequence per scene) and on a folder of scan
    folders (one per folder; a folder added later is labelled by the next tick)."""
    import shutil

    from flows.request import LabelRequest
    from flows.watch import auto_label
    from tasks.methods import stage_configs

    watched = tmp_path / "watched"
    shutil.copytree(logs[log], watched)
    request = LabelRequest(
        data=str(watched),
        root=str(tmp_path / "runs"),
        stages=stage_configs(scans=1, checkpoint=str(ckpt), clusterer=FAST_SHIFT),
    )
    params = request.model_dump(mode="json")
    seqs = ["scene-0001"] if log == "nuscenes" else ["drive1"]
    assert auto_label(params, dataset=log)["labelled"] == seqs
    store = RunStore(tmp_path / "runs")
    assert store.read_run_config()["format"] == log
    assert all(store.read_manifest(s, "track").status == "done" for s in seqs)  # k = 1: tracked
    assert auto_label(params, dataset=log)["labelled"] == []  # nothing new or stale
    if log == "folder":
        shutil.copytree(watched / "drive1", watched / "drive2")
        assert auto_label(params, dataset=log)["labelled"] == ["drive2"]


def _refused(output: str, code: int, *texts: str) -> str:
    """The one ``error:`` line of a refused command (exit 2, no traceback), holding ``texts``."""
    assert code == 2, output
    assert "Traceback" not in output, output
    lines = [line for line in output.splitlines() if line.startswith("error:")]
    assert len(lines) == 1, output
    line = " ".join(output[output.index("error:") :].split())  # rich may wrap the line
    for text in texts:
        assert text in line, (text, output)
    return line


def _cli_label(cli_env, log, run, *options: str):
    """``dsnet label`` as a user runs it (a subprocess: its terminal output is what is checked)."""
    import subprocess

    from tests.flows.conftest import cli

    res = subprocess.run(
        cli("label", str(log), "--run", str(run), *options),
        env=cli_env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    return res.stdout + res.stderr, res.returncode


def test_the_label_map_reader_option_works_in_describe_and_label(cli_env, logs, ckpt, tmp_path):
    # `--reader-option label_map=semantic-kitti` (documented) was an AttributeError in describe and ingest
    log = logs["semantickitti"]
    args = ["--reader-option", "label_map=semantic-kitti"]
    res = CliRunner().invoke(app, ["describe", str(log), *args], env={"COLUMNS": "240"})
    assert res.exit_code == 0, res.output
    assert "class histogram" in res.output and "car" in res.output
    out, code = _cli_label(
        cli_env, log, tmp_path / "run", "--checkpoint", str(ckpt), *args, "--until", "ingest"
    )
    assert code == 0, out
    store = RunStore(tmp_path / "run")
    assert store.read_run_config()["reader_options"] == {"label_map": "semantic-kitti"}
    assert store.read_table("00", FRAMES).to_pydict()["status"] == ["ok", "ok"]
    res = CliRunner().invoke(app, ["describe", str(log), "--reader-option", "label_map=nope"])
    want = ("reader option label_map='nope' is not allowed", "bundled label map")
    _refused(res.output, res.exit_code, *want)
    _refused(*_cli_label(cli_env, log, tmp_path / "r2", "--reader-option", "label_map=nope"), *want)
    assert not (tmp_path / "r2" / "run.json").exists()


@pytest.mark.parametrize(("value", "shown"), [("abc", "'abc'"), ("7", "7")])
def test_a_bad_bin_columns_value_is_refused_naming_the_option(logs, value, shown):
    # abc was a TypeError; 7 was accepted, then a misleading intensity error
    res = CliRunner().invoke(
        app, ["describe", str(logs["folder"]), "--reader-option", f"bin_columns={value}"]
    )
    _refused(
        res.output,
        res.exit_code,
        str(logs["folder"]),
        f"reader option bin_columns={shown} is not allowed",
        "4 or 5",
    )


def test_a_bag_whose_clouds_are_in_two_frames(cli_env, logs, ckpt, tmp_path):
    """With tf each frame gets its own pose and describe names both frames; without tf describe and
    label refuse in one line naming both (the bag used to describe itself as one frame id)."""
    ref = SemanticKittiReader(logs["semantickitti"])
    with_tf = write_bag(ref, tmp_path / "tf" / "run1", frame_ids=("velodyne", "rear"))
    res = CliRunner().invoke(app, ["describe", str(with_tf)], env={"COLUMNS": "240"})
    assert res.exit_code == 0, res.output
    assert "2 frames: velodyne ×1," in res.output and "rear ×1)" in res.output  # a wrapped cell
    assert "tf odom -> velodyne, rear" in res.output
    bare = write_bag(ref, tmp_path / "bare" / "run1", tf=None, frame_ids=("velodyne", "rear"))
    want = ("clouds on /points are in 2 frames (velodyne ×1, rear ×1) and no tf relates them", str(bare))
    res = CliRunner().invoke(app, ["describe", str(bare)])
    _refused(res.output, res.exit_code, *want)
    _refused(*_cli_label(cli_env, bare, tmp_path / "run", "--checkpoint", str(ckpt), "--scans", "1"), *want)
