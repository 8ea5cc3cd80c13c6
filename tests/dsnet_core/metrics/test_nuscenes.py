"""Panoptic nuScenes: npz files, PQ family, and the tracking metrics (LSTQ variant, PTQ, sPTQ, PAT).

Peer tests compare with nuscenes-devkit's ``PanopticEval`` and ``PanopticTrackingEval`` (installed
``--no-deps`` by ``make test``), driven exactly as its ``evaluate.py`` drives them.
"""

from __future__ import annotations

import numpy as np
import pytest

from dsnet_core.errors import LabelFormatError
from dsnet_core.metrics.nuscenes import (
    NuScenesCells,
    NuScenesPanopticEvaluator,
    read_panoptic_npz,
    write_panoptic_npz,
)
from dsnet_core.metrics.nuscenes_track import PanopticTrackingAccumulator
from tests.dsnet_core.metrics.nuscenes_peer import load_nuscenes_evaluators

try:
    PanopticEval, PanopticTrackingEval = load_nuscenes_evaluators()
except ImportError:  # pragma: no cover - exercised only without the peer
    PanopticEval = PanopticTrackingEval = None

peer = pytest.mark.skipif(
    PanopticEval is None,
    reason="peer evaluator missing: .venv/bin/pip install --no-deps nuscenes-devkit==1.2.0",
)
CELLS = NuScenesCells()
LUT = CELLS._gt.lut  # general -> challenge


def _scenes(seed: int, n_scenes: int = 2, frames: int = 5, n: int = 4000):
    """Scenes of persistent objects; predictions relabel points and switch some ids per frame."""
    rng = np.random.default_rng(seed)
    general = np.array(sorted(CELLS.label_map.learning_map))
    out = []
    for s in range(n_scenes):
        gcls = general[rng.integers(0, general.size, 40)]
        ginst = rng.integers(1, 30, 40)
        seq = []
        for _ in range(frames):
            obj = rng.integers(0, 40, n)
            ccls = LUT[gcls[obj]]
            thing = (ccls >= 1) & (ccls <= 10)
            gt = (gcls[obj] * 1000 + np.where(thing, ginst[obj], 0)).astype(np.uint16)
            pinst = np.where((rng.random(40) < 0.2)[obj], ginst[obj] + 1, ginst[obj])
            pred = (ccls * 1000 + np.where(thing, pinst, 0)).astype(np.uint16)
            m = rng.random(n) < 0.1
            pred[m] = (rng.integers(0, 17, m.sum()) * 1000 + rng.integers(0, 5, m.sum())).astype(np.uint16)
            seq.append((gt, pred))
        out.append((f"scene-{s:04d}", seq))
    return out


def test_npz_round_trip_and_errors(tmp_path):
    labels = np.array([0, 17001, 24000, 4005], dtype=np.uint16)
    path = tmp_path / "tok_panoptic.npz"
    write_panoptic_npz(path, labels)
    np.testing.assert_array_equal(read_panoptic_npz(path), labels)
    np.savez(tmp_path / "bad_panoptic.npz", labels=labels)
    with pytest.raises(LabelFormatError, match="has no 'data' array"):
        read_panoptic_npz(tmp_path / "bad_panoptic.npz")
    with pytest.raises(LabelFormatError, match="cannot read panoptic labels"):
        read_panoptic_npz(tmp_path / "missing_panoptic.npz")


def test_decoding_maps_general_to_challenge_classes():
    gt = np.array([17001, 17001, 24000, 2003, 0], dtype=np.uint16)  # car 1, driveable, adult 3, noise
    pred = np.array([4001, 4001, 11000, 7003, 0], dtype=np.uint16)
    c = CELLS(gt, pred)
    assert c.gt_cls.tolist() == [0, 7, 4, 11] and c.pred_cls.tolist() == [0, 7, 4, 11]
    with pytest.raises(ValueError, match="class 20"):
        CELLS(gt, np.array([20001] * 5, dtype=np.uint16))


def test_ground_truth_against_itself_is_perfect():
    ev = NuScenesPanopticEvaluator()
    trk = PanopticTrackingAccumulator(CELLS.spec)
    for name, frames in _scenes(3, n_scenes=1):
        for gt, _ in frames:
            pred = (LUT[gt // 1000] * 1000 + gt % 1000).astype(np.uint16)
            ev.add(gt, pred)
            trk.add(CELLS(gt, pred), name)
    present = [c for c in ev.result().per_class.values() if c.tp + c.fn > 0]
    assert len(present) > 5 and all(c.pq == 1.0 and c.iou == 1.0 for c in present)
    r = trk.result()
    # PTQ averages classes with ground truth; S_cls (and so PQ, LSTQ) count absent classes as 0
    assert (r.tq, r.ptq, r.sptq, r.s_assoc) == pytest.approx((1.0, 1.0, 1.0, 1.0), abs=1e-12)
    assert r.pq == pytest.approx(ev.result().pq) and r.s_cls == pytest.approx(len(present) / 16)
    d = r.to_dict()
    assert d["mode"] == "official" and d["tq"] == pytest.approx(1.0) and set(d["per_class_ptq"]) >= {"car"}


@pytest.mark.peer
@peer
@pytest.mark.parametrize(("seed", "min_points"), [(0, 15), (1, 1), (2, 40)])
def test_segmentation_matches_the_devkit(seed, min_points):
    ref = PanopticEval(n_classes=17, ignore=[0], min_points=min_points)
    ev = NuScenesPanopticEvaluator(min_points=min_points)
    for _, frames in _scenes(seed):
        for gt, pred in frames:
            ref.addBatch(pred // 1000, pred, LUT[gt // 1000], gt)
            ev.add(gt, pred)
    pq, sq, rq, all_pq, _, _ = ref.getPQ()
    miou, _ = ref.getSemIoU()
    r = ev.result()
    for ours, theirs in ((r.pq, pq), (r.sq, sq), (r.rq, rq), (r.miou, miou)):
        assert ours == pytest.approx(float(theirs), abs=1e-12, rel=0)
    np.testing.assert_allclose([c.pq for c in r.per_class.values()], all_pq[1:], atol=1e-12, rtol=0)


def _reference_tracking(scenes, min_points):
    ref = PanopticTrackingEval(n_classes=17, min_stuff_cls_id=11, ignore=[0], min_points=min_points)
    for name, frames in scenes:
        ps, pi, ls, li = [None], [None], [None], [None]
        for gt, pred in frames:  # the list juggling of the devkit's evaluate_tracking()
            ls.append(LUT[gt // 1000])
            ls = ls[-2:]
            li.append(gt)
            li = li[-2:]
            ps.append(pred // 1000)
            ps = ps[-2:]
            pi.append(pred)
            pi = pi[-2:]
            ref.add_batch(name, ps, pi, ls, li)
    pat, pq, tq = ref.get_pat()
    ptq, all_ptq, sptq, _ = ref.get_ptq()
    lstq, s_assoc = ref.get_lstq()
    miou, _ = ref.getSemIoU()
    return dict(pat=pat, pq=pq, tq=tq, ptq=ptq, sptq=sptq, lstq=lstq, s_assoc=s_assoc, miou=miou), all_ptq


@pytest.mark.peer
@peer
@pytest.mark.parametrize(("seed", "min_points"), [(0, 15), (1, 5), (2, 30)])
def test_tracking_matches_the_devkit(seed, min_points):
    scenes = _scenes(seed)
    expected, all_ptq = _reference_tracking(scenes, min_points)
    acc = PanopticTrackingAccumulator(CELLS.spec, min_points)
    for name, frames in scenes:
        for gt, pred in frames:
            acc.add(CELLS(gt, pred), name)
    r = acc.result()
    assert acc.ids.sum() > 0
    for key, value in expected.items():
        assert getattr(r, key) == pytest.approx(float(value), abs=1e-12, rel=0), key
    np.testing.assert_allclose(list(r.per_class_ptq.values()), all_ptq[1:], atol=1e-12, rtol=0)


def test_tracking_merge_of_consecutive_chunks_equals_one_pass():
    scenes = _scenes(4, frames=6)
    one = PanopticTrackingAccumulator(CELLS.spec)
    for name, frames in scenes:
        for gt, pred in frames:
            one.add(CELLS(gt, pred), name)
    # each scene split into three consecutive chunks, scenes interleaved across workers
    parts = [PanopticTrackingAccumulator(CELLS.spec) for _ in range(3)]
    for name, frames in scenes:
        for k, (gt, pred) in enumerate(frames):
            parts[k // 2].add(CELLS(gt, pred), name)
    total = PanopticTrackingAccumulator(CELLS.spec)
    for p in parts:
        total.merge(p)
    assert total.result() == one.result()
    np.testing.assert_array_equal(total.ids, one.ids)
