"""Equality with the public SemanticKITTI evaluator (``semantic-kitti-api==0.1``, module
``auxiliary.eval_np``; installed ``--no-deps`` by ``make test``), driven exactly as the
benchmark's ``evaluate_panoptic.py`` drives it."""

from __future__ import annotations

import contextlib
import io

import numpy as np
import pytest

from dsnet_core.metrics.evaluator import PanopticEvaluator
from tests.dsnet_core.metrics.frames import raw_frame

try:
    with contextlib.redirect_stdout(io.StringIO()):
        from auxiliary.eval_np import PanopticEval
except ImportError:  # pragma: no cover - exercised only without the peer
    PanopticEval = None

pytestmark = [
    pytest.mark.peer,
    pytest.mark.skipif(
        PanopticEval is None,
        reason="peer evaluator missing: .venv/bin/pip install --no-deps semantic-kitti-api==0.1",
    ),
]


def _reference(kitti, frames, min_points):
    maxkey = max(kitti.learning_map)
    lut = np.zeros(maxkey + 100, dtype=np.int32)
    lut[list(kitti.learning_map)] = list(kitti.learning_map.values())
    with contextlib.redirect_stdout(io.StringIO()):
        ref = PanopticEval(20, None, [0], min_points=min_points)
        for gt, pred in frames:
            ref.addBatch(lut[pred & 0xFFFF], pred, lut[gt & 0xFFFF], gt)
    return ref


@pytest.mark.parametrize(("seed", "min_points", "n_inst"), [(0, 50, 4), (1, 1, 12), (2, 15, 3000)])
def test_official_mode_matches_panoptic_eval(kitti, seed, min_points, n_inst):
    rng = np.random.default_rng(seed)
    frames = [raw_frame(rng, kitti, 12000, n_inst=n_inst, noise=0.25) for _ in range(4)]
    ref = _reference(kitti, frames, min_points)
    ev = PanopticEvaluator(kitti, min_points=min_points, mode="official")
    for k, (gt, pred) in enumerate(frames):
        ev.add(gt, pred, frame=str(k), sequence="08")
    r = ev.result().panoptic
    pq, sq, rq, all_pq, all_sq, all_rq = ref.getPQ()
    miou, all_iou = ref.getSemIoU()
    assert ref.pan_tp.sum() > 0
    np.testing.assert_array_equal(ev.panoptic.tp, ref.pan_tp)
    np.testing.assert_array_equal(ev.panoptic.fp, ref.pan_fp)
    np.testing.assert_array_equal(ev.panoptic.fn, ref.pan_fn)
    np.testing.assert_array_equal(ev.panoptic.conf, ref.px_iou_conf_matrix)
    for ours, theirs in ((r.pq, pq), (r.sq, sq), (r.rq, rq), (r.miou, miou)):
        assert ours == pytest.approx(float(theirs), abs=1e-12, rel=0)
    for k, c in enumerate(r.per_class.values(), start=1):
        assert (c.pq, c.sq, c.rq, c.iou) == pytest.approx(
            (all_pq[k], all_sq[k], all_rq[k], all_iou[k]), abs=1e-12, rel=0
        )
    things, stuff = list(range(1, 9)), list(range(9, 20))
    assert r.pq_dagger == pytest.approx(np.mean([*all_pq[things], *all_iou[stuff]]), abs=1e-12)
    assert r.pq_things == pytest.approx(np.mean(all_pq[things]), abs=1e-12)
    assert r.rq_stuff == pytest.approx(np.mean(all_rq[stuff]), abs=1e-12)


def test_ground_truth_vs_itself_matches_panoptic_eval(kitti):
    rng = np.random.default_rng(7)
    frames = [(gt, gt) for gt, _ in (raw_frame(rng, kitti, 8000) for _ in range(2))]
    ref = _reference(kitti, frames, 50)
    assert float(ref.getPQ()[0]) == 1.0


def test_reference_crashes_where_official_mode_refuses(kitti):
    """Ground-truth ids ≥ 32768 overflow the reference's int64 pair key (it raises KeyError)."""
    gt = np.full(100, 10 | (40000 << 16), dtype=np.uint32)
    pred = np.full(100, 10 | (7 << 16), dtype=np.uint32)
    with pytest.raises(KeyError):
        _reference(kitti, [(gt, pred)], 50)
    from dsnet_core.metrics.panoptic import ReferenceOverflowError

    with pytest.raises(ReferenceOverflowError):
        PanopticEvaluator(kitti).add(gt, pred)
