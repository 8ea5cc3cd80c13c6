"""A SemanticKITTI model's labels scored against Panoptic nuScenes ground truth, through the class
mapping: equal to nuscenes-devkit's evaluators reading the challenge-class results files the export
writes (all 16 classes, and the 12 the mapping can express with the other four ignored), and
block states that merge to the one-pass numbers exactly."""

from __future__ import annotations

import numpy as np
import pytest

from dsnet_core.errors import ConfigError
from dsnet_core.io.nuscenes_export import SceneEncoder
from dsnet_core.label_mapping import class_mapping
from dsnet_core.labels import LabelMap, load_label_map
from dsnet_core.metrics.nuscenes_scorer import NuScenesScorer
from dsnet_core.metrics.scoring import make_scorer, restore_scorer, scorer_state
from dsnet_core.metrics.state import state_from_bytes, state_to_bytes
from tests.dsnet_core.metrics.nuscenes_peer import load_nuscenes_evaluators

try:
    PanopticEval, PanopticTrackingEval = load_nuscenes_evaluators()
except ImportError:  # pragma: no cover - exercised only without the peer
    PanopticEval = PanopticTrackingEval = None

KITTI = load_label_map("semantic-kitti")
NUSC = load_label_map("panoptic-nuscenes")
LUT = NUSC.lut(66, fill=0)  # general -> challenge
UNEXPRESSIBLE_GENERAL = (9, 12, 18, 22)  # barrier, traffic cone, construction vehicle, trailer


def _scenes(seed: int, n_scenes: int = 2, frames: int = 4, n: int = 3000):
    """(scene, [(gt general | inst << 16, pred SemanticKITTI raw | inst << 16)]): persistent objects
    of SemanticKITTI classes (ground truth through the general-class encoder), some points of classes
    no SemanticKITTI class reaches, predictions relabelling points and switching some ids."""
    rng = np.random.default_rng(seed)
    raw = KITTI.inv_lut()
    out = []
    for s in range(n_scenes):
        cls = rng.integers(0, KITTI.num_classes, 30)
        inst = np.where(KITTI.is_thing()[cls], rng.integers(1, 20, 30), 0)
        enc = SceneEncoder(f"scene-{s}")
        seq = []
        for _ in range(frames):
            obj = rng.integers(0, 30, n)
            sk = (raw[cls[obj]] | (inst[obj] << 16)).astype(np.uint32)
            pan = enc.encode(sk).astype(np.uint32)
            hidden = rng.random(n) < 0.08  # ground truth a SemanticKITTI model cannot name
            pan[hidden] = np.asarray(UNEXPRESSIBLE_GENERAL)[rng.integers(0, 4, hidden.sum())] * 1000 + 1
            gt = (pan // 1000) | ((pan % 1000) << 16)
            pinst = np.where((rng.random(30) < 0.2)[obj], inst[obj] + 1, inst[obj])
            pred = (raw[cls[obj]] | (pinst << 16)).astype(np.uint32)
            noise = rng.random(n) < 0.1
            pred[noise] = raw[rng.integers(0, KITTI.num_classes, noise.sum())]
            seq.append((gt.astype(np.uint32), pred))
        out.append((f"scene-{s}", seq))
    return out


def _devkit(scenes, ignore):
    """nuscenes-devkit's evaluators on the results files the export writes (challenge classes)."""
    seg = PanopticEval(n_classes=17, ignore=ignore, min_points=15)
    track = PanopticTrackingEval(n_classes=17, min_stuff_cls_id=11, ignore=ignore, min_points=15)
    for name, frames in scenes:
        enc = SceneEncoder(name, classes="challenge")
        ps, pi, ls, li = [None], [None], [None], [None]
        for gt, pred in frames:
            result = enc.encode(pred).astype(np.int64)  # what OUT/panoptic/<split>/<token>_panoptic.npz holds
            truth = ((gt & 0xFFFF) * 1000 + (gt >> 16)).astype(np.int64)  # the log's panoptic file
            seg.addBatch(result // 1000, result, LUT[truth // 1000], truth)
            ls, li = [*ls, LUT[truth // 1000]][-2:], [*li, truth][-2:]
            ps, pi = [*ps, result // 1000][-2:], [*pi, result][-2:]
            track.add_batch(name, ps, pi, ls, li)
    pq, sq, rq, _, _, _ = seg.getPQ()
    miou, _ = seg.getSemIoU()
    pat, _, tq = track.get_pat()
    ptq, _, sptq, _ = track.get_ptq()
    lstq, _ = track.get_lstq()
    return {
        "pq": pq,
        "sq": sq,
        "rq": rq,
        "miou": miou,
        "pat": pat,
        "tq": tq,
        "ptq": ptq,
        "sptq": sptq,
        "lstq": lstq,
    }


@pytest.mark.peer
@pytest.mark.skipif(
    PanopticEval is None, reason="peer evaluator missing: pip install --no-deps nuscenes-devkit"
)
def test_scores_equal_the_devkit_on_the_exported_results():
    scenes = _scenes(0)
    scorer = make_scorer(NUSC, KITTI)
    assert isinstance(scorer, NuScenesScorer)
    for name, frames in scenes:
        for i, (gt, pred) in enumerate(frames):
            scorer.add(gt, pred, frame=str(i), sequence=name)
    summary = scorer.summary()
    assert summary["expressible"]["classes"] == [
        "bicycle", "bus", "car", "motorcycle", "pedestrian", "truck",
        "driveable_surface", "other_flat", "sidewalk", "terrain", "manmade", "vegetation",
    ]  # fmt: skip
    assert summary["mapping"]["unexpressible"] == [
        "barrier",
        "construction_vehicle",
        "traffic_cone",
        "trailer",
    ]
    for classes, ignore in (("all", [0]), ("expressible", [0, 1, 5, 8, 9])):
        want = _devkit(scenes, ignore)
        for key, value in want.items():
            assert summary[classes][key] == pytest.approx(float(value), abs=1e-12, rel=0), (classes, key)
    assert summary["all"]["pq"] < summary["expressible"]["pq"]  # the hidden classes score 0 in "all"


def test_block_states_merge_to_the_one_pass_numbers():
    scenes = _scenes(1, frames=5)
    one = make_scorer(NUSC, KITTI)
    blocks = [make_scorer(NUSC, KITTI) for _ in range(3)]
    for name, frames in scenes:
        for i, (gt, pred) in enumerate(frames):
            one.add(gt, pred, sequence=name)
            blocks[min(i // 2, 2)].add(gt, pred, sequence=name)  # consecutive chunks of every scene
    total = make_scorer(NUSC, KITTI)
    for b in blocks:
        total.merge(
            restore_scorer(make_scorer(NUSC, KITTI), state_from_bytes(state_to_bytes(scorer_state(b))))
        )
    assert total.summary() == one.summary()
    assert total.result().to_dict() == one.result().to_dict()


def test_ground_truth_made_from_the_predictions_scores_perfectly_on_expressible_classes():
    (name, frames), *_ = _scenes(2, n_scenes=1)
    scorer = make_scorer(NUSC, KITTI)
    enc = SceneEncoder(name)
    for pred in (p for _, p in frames):
        pan = enc.encode(pred).astype(np.uint32)
        scorer.add((pan // 1000) | ((pan % 1000) << 16), pred, sequence=name)
    assert scorer.result("expressible").panoptic.pq == 1.0 and scorer.tracking("expressible").pat == 1.0


def test_a_pair_of_maps_without_a_mapping_is_refused_naming_the_file():
    other = LabelMap(**{**vars(KITTI), "name": "my-classes"})
    with pytest.raises(
        ConfigError, match=r"no class mapping dsnet_core/data/my-classes-to-panoptic-nuscenes\.yaml"
    ):
        make_scorer(NUSC, other)
    assert class_mapping(KITTI, NUSC).record()["classes"]["other-vehicle"] == "bus"
