"""Panoptic nuScenes export: general-class encoding, ≤ 999 instances per class per scene, read back
and scored by our evaluator and by nuscenes-devkit's own ``PanopticEval``."""

from __future__ import annotations

import json
import subprocess

import numpy as np
import pytest

from dsnet_core.io.nuscenes_export import ExportError, SceneEncoder
from dsnet_core.io.semantickitti import SemanticKittiReader
from dsnet_core.labels import load_label_map
from dsnet_core.metrics import NuScenesPanopticEvaluator, read_panoptic_npz
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


def test_export_reads_back_and_scores_like_the_devkit(synth_log, tmp_path):
    (uri,) = score_runs(tmp_path, synth_log, {"run": 0.05}, bev=0)
    result = export_nuscenes(uri, tmp_path / "nusc")
    assert json.loads((tmp_path / "nusc/tokens.json").read_text()) == result.tokens
    cmd = cli("export", uri, "--out", str(tmp_path / "cli"), "--format", "nuscenes", "--sequences", "01")
    res = subprocess.run(
        cmd, cwd=REPO, env={"PYTHONPATH": str(REPO), "PATH": "/usr/bin:/bin"}, capture_output=True, text=True
    )
    assert res.returncode == 0, res.stderr
    assert "scene 01: 6 panoptic files" in res.stdout
    for token in result.tokens["01"]:
        name = f"panoptic/v1.0-trainval/{token}_panoptic.npz"
        assert np.array_equal(
            read_panoptic_npz(tmp_path / "cli" / name), read_panoptic_npz(tmp_path / "nusc" / name)
        )
    assert result.tokens["00"] == [f"00-{i:06d}" for i in range(6)]
    reader = SemanticKittiReader(synth_log)
    ours = NuScenesPanopticEvaluator()
    ref = PanopticEval(n_classes=17, ignore=[0], min_points=15) if PanopticEval else None
    for seq, tokens in result.tokens.items():
        gt_enc = SceneEncoder(seq)
        for ref_frame, token in zip(reader.frames(seq), tokens, strict=True):
            pred = read_panoptic_npz(result.folder / f"{token}_panoptic.npz")
            gt = gt_enc.encode(reader.labels(ref_frame))
            assert pred.shape == gt.shape and (pred % 1000).max() <= 999
            kitti = reader.labels(ref_frame)
            thing = np.isin(gt // 1000, [g for g in range(32) if LUT[g] in NUSC.things]) & (gt % 1000 > 0)
            pairs = np.unique(np.stack([kitti[thing], gt[thing]]), axis=1)  # one-to-one on thing points
            assert len(np.unique(pairs[0])) == len(np.unique(pairs[1])) == pairs.shape[1]
            challenge = LUT[pred // 1000] * 1000 + pred % 1000  # predictions use challenge classes
            ours.add(gt, challenge.astype(np.uint16))
            if ref is not None:
                ref.addBatch(LUT[pred // 1000], challenge, LUT[gt // 1000], gt)
    res = ours.result()
    assert 0.5 < res.pq < 1.0 and res.per_class["car"].tp > 0
    if ref is not None:
        pq, sq, rq, _, _, _ = ref.getPQ()
        assert abs(rq - res.rq) < 1e-12
        miou, _ = ref.getSemIoU()
        assert abs(pq - res.pq) < 1e-12 and abs(sq - res.sq) < 1e-12 and abs(miou - res.miou) < 1e-12
