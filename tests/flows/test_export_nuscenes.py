"""Panoptic nuScenes encoding: general classes (ground truth) and challenge classes (results for the
devkit), ≤ 999 instances per class per scene; results only for runs of nuScenes logs. The export of
a nuScenes run and its scores against the devkit: tests/flows/test_formats_e2e.py and
tests/dsnet_core/metrics/test_nuscenes_scorer.py."""

from __future__ import annotations

import subprocess

import numpy as np
import pytest

from dsnet_core.io.nuscenes_export import ExportError, SceneEncoder
from dsnet_core.labels import load_label_map
from flows.export_nuscenes import export_nuscenes
from tests.dsnet_core.metrics.nuscenes_peer import load_nuscenes_evaluators
from tests.flows.conftest import REPO, cli
from tests.tasks.oracle_stitch import score_runs

try:
    PanopticEval = load_nuscenes_evaluators()[0]
except ImportError:  # pragma: no cover - exercised only without the peer
    PanopticEval = None

NUSC = load_label_map("panoptic-nuscenes")
LUT = np.array([NUSC.learning_map.get(g, 0) for g in range(66)])  # general -> challenge


def test_encoder_keeps_instances_apart_and_stable_across_frames():
    car, person, road = 10, 30, 40
    f0 = np.array(
        [car | 5 << 16] * 3 + [car | 9 << 16] * 2 + [person | 5 << 16] + [road, road], dtype=np.uint32
    )
    f1 = np.array([car | 9 << 16, car | 7 << 16, road, car], dtype=np.uint32)
    enc = SceneEncoder("00")
    a, b = enc.encode(f0), enc.encode(f1)
    assert a.dtype == np.uint16
    assert a.tolist() == [17001] * 3 + [17002] * 2 + [2001] + [24000, 24000]
    assert b.tolist() == [17002, 17003, 24000, 17000]  # id 9 keeps its number, 7 is new
    many = np.array([car | (i + 1) << 16 for i in range(1000)], dtype=np.uint32)
    with pytest.raises(
        ExportError, match=r"scene 07: more than 999 instances of nuScenes class vehicle\.car"
    ):
        SceneEncoder("07").encode(many)


def test_challenge_encoding_numbers_instances_per_written_class():
    """Results for the devkit hold challenge classes: SemanticKITTI bicycle and bicyclist both reach
    nuScenes bicycle, so their instances share one counter; stuff points carry no instance."""
    car, bicycle, bicyclist, road = 10, 11, 31, 40
    labels = np.array(
        [bicycle | 4 << 16, bicyclist | 9 << 16, car | 4 << 16, road | 7 << 16], dtype=np.uint32
    )
    out = SceneEncoder("00", classes="challenge").encode(labels)
    assert out.tolist() == [2001, 2002, 4001, 11000]  # bicycle, bicycle, car, driveable_surface
    assert (LUT[SceneEncoder("00").encode(labels) // 1000] == out // 1000).all()  # general -> challenge


def test_nuscenes_results_need_a_nuscenes_log(synth_log, tmp_path):
    """Results are keyed by sample_data tokens: a run of a SemanticKITTI log has none."""
    (uri,) = score_runs(tmp_path, synth_log, {"run": 0.05}, sequences=("00",), bev=0)
    with pytest.raises(ExportError, match="only a nuscenes log has"):
        export_nuscenes(uri, tmp_path / "nusc")
    res = subprocess.run(
        cli("export", uri, "--out", str(tmp_path / "cli"), "--format", "nuscenes"),
        cwd=REPO, env={"PYTHONPATH": str(REPO), "PATH": "/usr/bin:/bin"}, capture_output=True, text=True,
    )  # fmt: skip
    assert res.returncode == 2 and "sample_data tokens" in res.stderr
    res = subprocess.run(  # the run's own format by default
        cli("export", uri, "--out", str(tmp_path / "cli")),
        cwd=REPO, env={"PYTHONPATH": str(REPO), "PATH": "/usr/bin:/bin"}, capture_output=True, text=True,
    )  # fmt: skip
    assert res.returncode == 0 and "wrote semantickitti labels" in res.stdout
