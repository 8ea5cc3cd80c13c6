"""LSTQ (4D benchmark semantics): hand-built sequences for each rule, both modes, golden cases.

4D-PLS's ``Panoptic4DEval`` is not installable from PyPI, so official mode is checked against
``ref_4dpls.Ref4DPLS``, a literal loop-per-class transcription of docs/metrics.md ("spec-derived
golden cases"), and against hand-computed values.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from dsnet_core.metrics.evaluator import PanopticEvaluator
from tests.dsnet_core.metrics.frames import random_sequence
from tests.dsnet_core.metrics.ref_4dpls import Ref4DPLS

CAR, TRUCK, ROAD, SIDEWALK = 1, 4, 9, 11


def _frame(*parts):
    """Concatenate ``(n, sem, inst)`` blocks into ``(sem, inst)`` train-id arrays."""
    sem = np.concatenate([np.full(n, s) for n, s, _ in parts])
    inst = np.concatenate([np.full(n, i) for n, _, i in parts])
    return sem, inst


def _score(kitti, frames, mode="official", min_points=50):
    ev = PanopticEvaluator(kitti, min_points=min_points, mode=mode)
    for k, (gt, pred) in enumerate(frames):
        ev.add_train(*gt, *pred, frame=f"{k:06d}", sequence="00")
    return ev.result().lstq


def test_ground_truth_against_itself_with_clean_ids_is_one_in_both_modes(kitti):
    f = _frame((100, CAR, 1), (80, CAR, 2), (200, ROAD, 0), (60, TRUCK, 3))
    for mode in ("official", "corrected"):
        r = _score(kitti, [(f, f), (f, f)], mode)
        assert (r.lstq, r.s_assoc, r.s_cls, r.n_tubes) == (1.0, 1.0, 1.0, 3)


def test_small_fragments_break_gt_vs_gt_in_official_mode_only(kitti):
    # car 1 has 100 points in frame 0 and 30 (≤ 50) in frame 1: dropped from its tube but still
    # counted in the predicted size -> IoU 100/130
    f0 = _frame((100, CAR, 1), (100, ROAD, 0))
    f1 = _frame((30, CAR, 1), (100, ROAD, 0))
    off = _score(kitti, [(f0, f0), (f1, f1)], "official")
    assert off.s_assoc == pytest.approx(100 / 130, abs=1e-15)
    cor = _score(kitti, [(f0, f0), (f1, f1)], "corrected")
    assert cor.s_assoc == 1.0 and cor.lstq == 1.0


def test_stuff_ids_break_gt_vs_gt_in_official_mode_only(kitti):
    # road carries instance id 7: its tube adds to the numerator but not to the denominator
    f = _frame((100, CAR, 1), (100, ROAD, 7))
    off = _score(kitti, [(f, f)], "official")
    assert off.s_assoc == 2.0 and off.n_tubes == 1
    # a stuff id shared with a thing: the prediction's size grows
    g = _frame((100, CAR, 1), (300, ROAD, 1), (100, CAR, 2))
    assert _score(kitti, [(g, g)], "official").s_assoc == pytest.approx((0.25 + 0.75 + 1.0) / 2)
    for frame in (f, g):
        assert _score(kitti, [(frame, frame)], "corrected").s_assoc == 1.0


def test_tube_needs_strictly_more_than_min_points(kitti):
    f50 = _frame((50, CAR, 1), (100, CAR, 2))
    f51 = _frame((51, CAR, 1), (100, CAR, 2))
    assert _score(kitti, [(f50, f50)]).n_tubes == 1
    assert _score(kitti, [(f51, f51)]).n_tubes == 2


def test_ids_are_class_agnostic(kitti):
    # car 1 predicted half as truck, same id: association is perfect, semantics are not
    gt = _frame((100, CAR, 1), (100, ROAD, 0))
    pred = _frame((50, CAR, 1), (50, TRUCK, 1), (100, ROAD, 0))
    for mode in ("official", "corrected"):
        r = _score(kitti, [(gt, pred)], mode)
        assert r.s_assoc == 1.0
        assert r.per_class_iou["car"] == 0.5


def test_one_point_predicted_as_class_0_changes_the_official_divisor(kitti):
    gt = _frame((100, ROAD, 0))
    pred = _frame((99, ROAD, 0), (1, 0, 0))
    off = _score(kitti, [(gt, pred)], "official")
    assert off.s_cls == pytest.approx(0.99 / 2)  # classes with a union: road and class 0
    cor = _score(kitti, [(gt, pred)], "corrected")
    assert cor.s_cls == pytest.approx(0.99)
    # absent classes are excluded in both modes
    both = _score(kitti, [(_frame((100, ROAD, 0), (100, SIDEWALK, 0)),) * 2], "official")
    assert both.s_cls == 1.0


def test_predicted_class_0_with_ids_counts_in_intersections_only_officially(kitti):
    gt = _frame((100, CAR, 1))
    pred = _frame((60, CAR, 1), (40, 0, 1))
    off = _score(kitti, [(gt, pred)], "official")
    # |p| = 60 (class-0 points not counted), TPA = 100 -> 100·(100/(100 + 60 − 100)) / 100
    assert off.s_assoc == pytest.approx(100 / 60)
    cor = _score(kitti, [(gt, pred)], "corrected")
    assert cor.s_assoc == pytest.approx(60 * (60 / 100) / 100)


def test_no_thing_tube_gives_nan_not_an_exception(kitti):
    f = _frame((100, ROAD, 0))
    r = _score(kitti, [(f, f)])
    assert math.isnan(r.s_assoc) and math.isnan(r.lstq) and r.n_tubes == 0


def test_result_is_idempotent_unlike_the_reference(kitti):
    rng = np.random.default_rng(5)
    ev = PanopticEvaluator(kitti, min_points=5)
    ref = Ref4DPLS(min_points=5)
    for gs, gi, ps, pi in random_sequence(rng, 3, 3000):
        ev.add_train(gs, gi, ps, pi, sequence="04")
        ref.add("04", ps, pi, gs, gi)
    first, second = ev.result(), ev.result()
    assert first == second
    s1, s2 = ref.get()[1], ref.get()[1]
    assert s2 == pytest.approx(2 * s1)  # the reference's documented defect


@pytest.mark.parametrize(("seed", "mp", "n", "n_inst"), [(0, 0, 3000, 8), (1, 5, 4000, 8), (2, 50, 20000, 4)])
def test_official_mode_equals_the_literal_transcription(kitti, seed, mp, n, n_inst):
    rng = np.random.default_rng(seed)
    ev = PanopticEvaluator(kitti, min_points=mp)
    ref = Ref4DPLS(min_points=mp)
    for seq in ("00", "01"):
        for gs, gi, ps, pi in random_sequence(rng, 4, n, n_inst=n_inst):
            ev.add_train(gs, gi, ps, pi, sequence=seq)
            ref.add(seq, ps, pi, gs, gi)
    r = ev.result().lstq
    lstq, s_assoc, s_cls, iou = ref.get()
    assert r.n_tubes > 0
    assert r.s_assoc == pytest.approx(s_assoc, abs=1e-12, rel=0)
    assert r.s_cls == pytest.approx(s_cls, abs=1e-12, rel=0)
    assert r.lstq == pytest.approx(lstq, abs=1e-12, rel=0)
    assert r.iou_things == pytest.approx(iou[1:9].mean(), abs=1e-12)
    assert r.iou_stuff == pytest.approx(iou[9:].mean(), abs=1e-12)


def test_the_4dpls_self_test_example():
    """The worked example in 4D-PLS's eval_np.py ``__main__``: LSTQ = sqrt(1/3), S_assoc = 2/3."""
    from dsnet_core.metrics.decode import ClassSpec, TrainDecoder, make_cells, train_labels
    from dsnet_core.metrics.lstq import LSTQAccumulator

    spec = ClassSpec(("ignore", "car", "truck"), things=(1, 2), stuff=())
    sem_gt, inst_gt = np.zeros(20, int), np.zeros(20, int)
    sem_gt[5:10], sem_gt[10:] = 1, 2
    inst_gt[5:10], inst_gt[10:], inst_gt[15:] = 1, 1, 2
    sem_pred, inst_pred = np.zeros(20, int), np.zeros(20, int)
    sem_pred[5:10], sem_pred[10:15], sem_pred[15:] = 1, 2, 1
    inst_pred[5:10], inst_pred[10:] = 1, 2
    acc = LSTQAccumulator(spec, min_points=1)
    gt, pred = train_labels(sem_gt, inst_gt, 3, "gt"), train_labels(sem_pred, inst_pred, 3, "pred")
    acc.add(make_cells(gt, pred, TrainDecoder(), TrainDecoder()), "1")
    r = acc.result()
    assert r.lstq == pytest.approx(np.sqrt(1.0 / 3), abs=1e-15)
    assert r.s_assoc == pytest.approx(2.0 / 3, abs=1e-15) and r.s_cls == 0.5
    assert r.per_class_iou == {"car": 0.5, "truck": 0.5}
    _, _, per_class = acc.association()
    np.testing.assert_allclose(per_class / np.maximum([0, 1, 2], 1e-15), [0, 1.0, 0.5])
