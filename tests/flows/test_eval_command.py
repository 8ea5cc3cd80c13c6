"""``dsnet eval`` end to end on a small SemanticKITTI-layout log and a perturbed copy of it."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from dsnet_core.io import kitti
from dsnet_core.io.semantickitti import write_frame
from dsnet_core.labels import load_label_map
from dsnet_core.metrics.evaluator import PanopticEvaluator
from flows.cli import app

ROOT = Path(__file__).resolve().parents[2]
KEYS = {
    "mode", "pq", "pq_dagger", "sq", "rq", "pq_things", "sq_things", "rq_things", "pq_stuff",
    "sq_stuff", "rq_stuff", "miou", "lstq", "s_assoc", "s_cls", "iou_stuff", "iou_things",
    "per_class", "frames",
    "miou_present", "pq_present", "sq_present", "rq_present", "present_classes",  # metric ``present``
}  # fmt: skip


def _scene_labels(rng: np.random.Generator, n: int = 3000) -> np.ndarray:
    """Road, building, vegetation and three cars (raw ids), uint32 ``(n,)``."""
    parts = [
        (40, 0, 900),
        (60, 0, 100),
        (50, 0, 700),
        (70, 0, 600),
        (10, 1, 300),
        (10, 2, 250),
        (252, 3, 150),
    ]
    lab = np.concatenate([np.full(k, sem | (inst << 16), dtype=np.uint32) for sem, inst, k in parts])
    return lab[rng.permutation(n)]


def _perturb(rng: np.random.Generator, gt: np.ndarray) -> np.ndarray:
    pred = gt.copy()
    sem, inst = pred & 0xFFFF, pred >> 16
    flip = rng.random(gt.size) < 0.05
    pred[flip] = 48  # relabel some points as sidewalk
    car2 = np.flatnonzero(inst == 2)
    pred[car2[: car2.size // 2]] = 10 | (7 << 16)  # split car 2
    pred[inst == 3] = 10 | (1 << 16)  # merge car 3 (moving) into car 1
    pred[(sem == 60) & ~flip] = 40  # lane marking predicted as road
    return pred.astype(np.uint32)


@pytest.fixture(scope="module")
def log(tmp_path_factory):
    rng = np.random.default_rng(0)
    gt_root = tmp_path_factory.mktemp("gt")
    pred_root = tmp_path_factory.mktemp("pred")
    frames = []
    for seq in ("08", "13"):
        for k in range(3):
            gt = _scene_labels(rng)
            pred = _perturb(rng, gt)
            name = f"{k:06d}"
            write_frame(gt_root / "sequences" / seq, name, np.zeros((gt.size, 4), np.float32), gt)
            kitti.write_label(pred_root / "sequences" / seq / "predictions" / f"{name}.label", pred)
            frames.append((seq, name, gt, pred))
    return gt_root, pred_root, frames


def test_eval_subprocess_writes_the_json_report(log, tmp_path):
    gt_root, pred_root, frames = log
    out = tmp_path / "scores.json"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    cmd = [sys.executable, "-m", "flows.cli", "eval", "--gt", str(gt_root), "--pred", str(pred_root)]
    proc = subprocess.run(
        [*cmd, "--sequences", "08,13", "--json", str(out)], cwd=ROOT, env=env, capture_output=True, text=True
    )
    assert proc.returncode == 0, proc.stderr
    assert "panoptic scores (6 frames, mode: official)" in proc.stdout and "LSTQ" in proc.stdout
    report = json.loads(out.read_text())
    assert set(report) == KEYS and report["frames"] == 6 and report["mode"] == "official"
    ev = PanopticEvaluator(load_label_map("semantic-kitti"))
    for seq, name, gt, pred in frames:
        ev.add(gt, pred, frame=name, sequence=seq)
    assert report == json.loads(json.dumps(ev.result().to_dict()))
    assert 0 < report["pq"] < 1 and 0 < report["lstq"] < 1
    assert set(report["per_class"]["car"]) == {"pq", "sq", "rq", "iou"}
    assert len(report["per_class"]) == 19


def _invoke(*args):
    return CliRunner().invoke(app, ["eval", *map(str, args)])


def test_default_sequences_are_those_with_both_and_the_mode_is_reported(log, tmp_path):
    gt_root, pred_root, _ = log
    out = tmp_path / "s.json"
    res = _invoke(
        "--gt", gt_root, "--pred", pred_root, "--mode", "corrected", "--json", out, "--min-points", 10
    )
    assert res.exit_code == 0, res.output
    assert "scoring sequences 08, 13 (those with ground truth and predictions)" in res.output
    report = json.loads(out.read_text())
    assert report["frames"] == 6 and report["mode"] == "corrected"
    only = tmp_path / "only13"
    shutil.copytree(pred_root / "sequences" / "13", only / "sequences" / "13")
    res = _invoke("--gt", gt_root, "--pred", only, "--json", out)
    assert res.exit_code == 0 and "scoring sequences 13 " in res.output, res.output
    assert json.loads(out.read_text())["frames"] == 3
    res = _invoke("--gt", gt_root, "--pred", tmp_path / "empty")
    assert res.exit_code == 2 and "no sequence has both ground truth" in res.output


def test_a_run_store_as_predictions_says_to_export_first(log, tmp_path):
    gt_root, _, _ = log
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "run.json").write_text("{}")
    res = _invoke("--gt", gt_root, "--pred", tmp_path / "run")
    assert res.exit_code == 2 and f"dsnet export {tmp_path / 'run'} --out DIR" in res.output.replace("\n", "")


def test_missing_extra_and_mismatched_predictions_are_named(log, tmp_path):
    gt_root, pred_root, _ = log
    bad = tmp_path / "pred"
    src = pred_root / "sequences" / "08" / "predictions"
    dst = bad / "sequences" / "08" / "predictions"
    dst.mkdir(parents=True)
    for p in src.glob("*.label"):
        (dst / p.name).write_bytes(p.read_bytes())
    (dst / "000001.label").unlink()
    res = _invoke("--gt", gt_root, "--pred", bad, "--sequences", "8")
    assert res.exit_code == 2
    assert "000001.label: prediction missing for ground truth" in res.output
    (dst / "000001.label").write_bytes((src / "000001.label").read_bytes())
    (dst / "000009.label").write_bytes((src / "000001.label").read_bytes())
    res = _invoke("--gt", gt_root, "--pred", bad, "--sequences", "08")
    assert res.exit_code == 2 and "000009.label: prediction has no ground truth" in res.output
    (dst / "000009.label").unlink()
    (dst / "000002.label").write_bytes((src / "000002.label").read_bytes()[:-8])
    res = _invoke("--gt", gt_root, "--pred", bad, "--sequences", "08")
    assert res.exit_code == 2
    assert "000002.label: has 2998 labels but the ground truth" in res.output
    res = _invoke("--gt", gt_root, "--pred", bad, "--sequences", "13")
    assert res.exit_code == 2 and "prediction folder of sequence 13 does not exist" in res.output
    res = _invoke("--gt", gt_root, "--pred", pred_root, "--sequences", "08", "--mode", "exact")
    assert res.exit_code == 2 and "unknown scoring mode 'exact'" in res.output


def test_data_config_sets_split_and_ignored_classes(log, tmp_path):
    import yaml

    gt_root, pred_root, frames = log
    data = yaml.safe_load((ROOT / "dsnet_core" / "data" / "semantic-kitti.yaml").read_text())
    data["split"]["valid"] = [13]
    data["learning_ignore"][11] = True  # sidewalk (the perturbation's relabel target) ignored
    cfg = tmp_path / "cfg.yaml"
    cfg.write_text(yaml.safe_dump(data))
    out = tmp_path / "s.json"
    res = _invoke(
        "--gt", gt_root, "--pred", pred_root, "--data-config", cfg, "--json", out, "--sequences", "13"
    )
    assert res.exit_code == 0, res.output
    report = json.loads(out.read_text())
    assert report["frames"] == 3 and "sidewalk" not in report["per_class"] and len(report["per_class"]) == 18
    ev = PanopticEvaluator(load_label_map(cfg), ignore=(0, 11))
    for seq, name, gt, pred in frames:
        if seq == "13":
            ev.add(gt, pred, frame=name, sequence=seq)
    assert report["pq"] == ev.result().panoptic.pq


def test_learning_ignore_as_a_list_scores_like_the_mapping(log, tmp_path):
    import yaml

    gt_root, pred_root, _ = log
    data = yaml.safe_load((ROOT / "dsnet_core" / "data" / "semantic-kitti.yaml").read_text())
    data["learning_ignore"] = [0, 11]  # a list of train ids instead of the {id: bool} mapping
    cfg = tmp_path / "cfg.yaml"
    cfg.write_text(yaml.safe_dump(data))
    out = tmp_path / "s.json"
    res = _invoke(
        "--gt", gt_root, "--pred", pred_root, "--sequences", "08", "--data-config", cfg, "--json", out
    )
    assert res.exit_code == 0, res.output
    assert "sidewalk" not in json.loads(out.read_text())["per_class"]


def test_raw_ids_the_label_map_does_not_know_are_refused_naming_the_file(log, tmp_path):
    gt_root, pred_root, _ = log
    bad = tmp_path / "pred" / "sequences" / "08" / "predictions"
    bad.mkdir(parents=True)
    for p in (pred_root / "sequences" / "08" / "predictions").glob("*.label"):
        (bad / p.name).write_bytes(p.read_bytes())
    label = kitti.read_label(bad / "000001.label")
    label[:5] = 12  # raw id 12: no SemanticKITTI class
    kitti.write_label(bad / "000001.label", label)
    res = _invoke("--gt", gt_root, "--pred", tmp_path / "pred", "--sequences", "08")
    assert res.exit_code == 2 and "000001.label" in res.output and "12" in res.output, res.output
    assert "Traceback" not in res.output


def test_bad_options_are_refused_before_scoring(log, tmp_path):
    gt_root, pred_root, _ = log
    res = _invoke("--gt", gt_root, "--pred", pred_root, "--sequences", "08", "--json", tmp_path)
    assert res.exit_code == 2 and "is a folder" in res.output and "Traceback" not in res.output
    res = _invoke("--gt", gt_root, "--pred", pred_root, "--sequences", "08", "--min-points", -5)
    assert res.exit_code == 2 and "--min-points" in res.output


def _predictions_from(log_root: Path, out_root: Path, perturb) -> None:
    for label in sorted(log_root.glob("sequences/*/labels/*.label")):
        seq = label.parent.parent.name
        pred = perturb(kitti.read_label(label))
        kitti.write_label(out_root / "sequences" / seq / "predictions" / label.name, pred)


def test_eval_on_a_synth_log_against_itself_and_a_perturbed_copy(synth_log, tmp_path):
    same, noisy = tmp_path / "same", tmp_path / "noisy"
    _predictions_from(synth_log, same, lambda lab: lab)
    rng = np.random.default_rng(3)
    _predictions_from(synth_log, noisy, lambda lab: _perturb(rng, lab))
    reports = {}
    for name, pred, mode in (
        ("same", same, "corrected"),
        ("same_off", same, "official"),
        ("noisy", noisy, "official"),
    ):
        out = tmp_path / f"{name}.json"
        res = _invoke(
            "--gt", synth_log, "--pred", pred, "--sequences", "00,01", "--mode", mode, "--json", out
        )
        assert res.exit_code == 0, res.output
        reports[name] = json.loads(out.read_text())
    same_r, off_r, noisy_r = reports["same"], reports["same_off"], reports["noisy"]
    assert same_r["frames"] == 12 and same_r["mode"] == "corrected"
    present = [c for c in same_r["per_class"].values() if c["iou"] > 0]
    assert len(present) >= 5 and all(c["pq"] == 1.0 and c["iou"] == 1.0 for c in present)
    assert same_r["lstq"] == 1.0 and same_r["s_assoc"] == 1.0 and same_r["s_cls"] == 1.0
    assert off_r["pq"] == same_r["pq"] and off_r["s_assoc"] <= 1.0
    assert noisy_r["pq"] < same_r["pq"] and noisy_r["lstq"] < 1.0
