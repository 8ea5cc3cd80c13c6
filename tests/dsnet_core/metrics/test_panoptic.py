"""PQ family and mIoU: the paper's toy example and one hand-built frame per rule of docs/metrics.md."""

from __future__ import annotations

import numpy as np
import pytest

from dsnet_core.metrics.decode import ClassSpec, KittiDecoder, TrainDecoder, make_cells, train_labels
from dsnet_core.metrics.evaluator import PanopticEvaluator
from dsnet_core.metrics.panoptic import PanopticAccumulator, ReferenceOverflowError

TOY = ClassSpec(("ignore", "grass", "sky", "person", "dog"), things=(3, 4), stuff=(1, 2))


def _toy_frame():
    """The 2D toy of Kirillov et al. as laid out in semantic-kitti-api's eval_np self-test."""
    sem_p, inst_p, sem_g, inst_g = [], [], [], []

    def put(sp, ip, sg, ig, n):
        sem_p.extend([sp] * n), inst_p.extend([ip] * n), sem_g.extend([sg] * n), inst_g.extend([ig] * n)

    put(0, 0, 0, 0, 50)  # ignore
    put(1, 0, 1, 0, 40)  # grass, 10 of its points predicted sky
    put(2, 0, 1, 0, 10)
    put(2, 0, 2, 0, 40)  # sky, 10 of its points predicted grass
    put(1, 0, 2, 0, 10)
    put(3, 35, 4, 22, 50)  # a dog predicted as a person
    put(3, 8, 3, 33, 150)  # three persons in gt, two predicted
    put(3, 8, 3, 42, 50)
    put(3, 95, 3, 11, 100)
    return [np.array(a) for a in (sem_g, inst_g, sem_p, inst_p)]


def _score(spec, gs, gi, ps, pi, min_points=1, mode="official"):
    acc = PanopticAccumulator(spec, min_points, mode)
    dec = TrainDecoder()
    n = spec.n_classes
    acc.add(make_cells(train_labels(gs, gi, n, "gt"), train_labels(ps, pi, n, "pred"), dec, dec))
    return acc


def test_toy_example_of_the_pq_paper():
    acc = _score(TOY, *_toy_frame())
    r = acc.result()
    assert r.pq == pytest.approx(0.47916666666666663, abs=1e-15)
    assert r.sq == pytest.approx(0.5520833333333333, abs=1e-15)
    assert r.rq == pytest.approx(0.6666666666666666, abs=1e-15)
    assert r.miou == pytest.approx(0.5476190476190476, abs=1e-15)
    person = r.per_class["person"]
    assert (person.pq, person.sq, person.rq) == pytest.approx((0.5833333333333333, 0.875, 2 / 3))
    assert person.iou == pytest.approx(0.8571428571428571)
    assert r.per_class["dog"].pq == 0.0 and r.per_class["dog"].iou == 0.0
    assert r.mode == "official"


def test_ground_truth_against_itself_is_perfect(kitti):
    from tests.dsnet_core.metrics.frames import raw_frame

    rng = np.random.default_rng(0)
    for mode in ("official", "corrected"):
        ev = PanopticEvaluator(kitti, mode=mode)
        for f in range(3):
            gt, _ = raw_frame(rng, kitti, 4000)
            ev.add(gt, gt, frame=str(f), sequence="00")
        r = ev.result().panoptic
        assert r.pq == 1.0 and r.miou == 1.0 and r.sq == 1.0 and r.rq == 1.0 and r.pq_dagger == 1.0


def _one_class(gt_ids, pred_ids, min_points=1, things=(1,)):
    spec = ClassSpec(("void", "car", "road"), things=things, stuff=tuple({1, 2} - set(things)))
    gs = np.ones(len(gt_ids), dtype=np.int64)
    return _score(spec, gs, np.array(gt_ids), gs.copy(), np.array(pred_ids), min_points)


def test_iou_of_exactly_one_half_is_not_a_match():
    # gt segment 4 points, pred segment 4 points, overlap 3 of union... build IoU = 0.5 exactly:
    # gt = {a,b}, pred = {a,b,c,d} -> IoU = 2/4
    acc = _one_class([1, 1, 0, 0], [1, 1, 1, 1])
    assert acc.tp[1] == 0 and acc.fn[1] == 2 and acc.fp[1] == 1
    # one more shared point: IoU = 3/5 > 0.5 is a match
    acc = _one_class([1, 1, 1, 0, 0], [1, 1, 1, 1, 1])
    assert acc.tp[1] == 1 and acc.iou_sum[1] == pytest.approx(0.6) and acc.fp[1] == 0 and acc.fn[1] == 1


def test_min_points_is_inclusive_for_unmatched_segments():
    # unmatched gt segment of exactly 3 points counts with min_points=3, not with 4
    gt = [5, 5, 5] + [6] * 10
    pred = [7, 7, 7] + [6] * 10  # pred 7 overlaps gt 5 fully... make it unmatched: pred splits it
    pred = [7, 8, 9] + [6] * 10
    for mp, fn in ((3, 1), (4, 0)):
        acc = _one_class(gt, pred, min_points=mp)
        assert acc.fn[1] == fn and acc.tp[1] == 1
        assert acc.fp[1] == 0  # the 1-point predictions are below min_points


def test_matched_segments_have_no_size_limit():
    acc = _one_class([3, 3], [4, 4], min_points=50)
    assert acc.tp[1] == 1 and acc.iou_sum[1] == 1.0


def test_whole_label_is_the_segment_key_so_lane_marking_splits_road(kitti):
    # road (raw 40) and lane-marking (raw 60) both map to train class road; ground truth has two
    # segments, the prediction one: 60 road + 40 lane points vs one predicted road of 100 points.
    road = kitti.learning_map[40]
    assert kitti.learning_map[60] == road
    gt = np.array([40] * 60 + [60] * 40, dtype=np.uint32)
    pred = np.full(100, 40, dtype=np.uint32)
    ev = PanopticEvaluator(kitti, min_points=1)
    ev.add(gt, pred)
    c = ev.result().panoptic.per_class["road"]
    assert (c.tp, c.fp, c.fn) == (1, 0, 1)
    assert c.sq == pytest.approx(0.6) and c.iou == 1.0
    # thing points without instance form one segment per raw label: moving-car vs car
    car = np.array([10] * 70 + [252] * 30, dtype=np.uint32)
    ev = PanopticEvaluator(kitti, min_points=1)
    ev.add(car, np.full(100, 10, dtype=np.uint32))
    c = ev.result().panoptic.per_class["car"]
    assert (c.tp, c.fp, c.fn) == (1, 0, 1)


def test_absent_classes_count_zero_in_the_means(kitti):
    gt = np.full(100, 40, dtype=np.uint32)  # only road
    ev = PanopticEvaluator(kitti, min_points=1)
    ev.add(gt, gt)
    r = ev.result().panoptic
    assert r.per_class["road"].pq == 1.0
    assert r.pq == pytest.approx(1 / 19) and r.miou == pytest.approx(1 / 19)
    assert r.pq_stuff == pytest.approx(1 / 11) and r.pq_things == 0.0


def test_ignored_ground_truth_is_dropped_but_predicted_ignore_is_a_miss(kitti):
    gt = np.array([0] * 50 + [40] * 50, dtype=np.uint32)  # 50 unlabeled, 50 road
    pred = np.array([40] * 50 + [0] * 10 + [40] * 40, dtype=np.uint32)
    ev = PanopticEvaluator(kitti, min_points=1)
    ev.add(gt, pred)
    c = ev.result().panoptic.per_class["road"]
    assert c.iou == pytest.approx(40 / 50)  # predicting 0 on valid road is a false negative
    assert c.tp == 1 and c.sq == pytest.approx(40 / 50)


def test_unknown_raw_ids_are_ignored_not_a_crash(kitti):
    gt = np.array([40] * 10 + [400] * 10 + [65535] * 5, dtype=np.uint32)
    pred = np.array([40] * 10 + [40] * 10 + [999] * 5, dtype=np.uint32)
    ev = PanopticEvaluator(kitti, min_points=1)
    row = ev.add(gt, pred)
    assert row.n_valid == 10 and ev.result().panoptic.per_class["road"].pq == 1.0


def test_instance_ids_from_32768_need_corrected_mode(kitti):
    gt = np.full(100, 10 | (40000 << 16), dtype=np.uint32)
    pred = np.full(100, 10 | (7 << 16), dtype=np.uint32)
    with pytest.raises(ReferenceOverflowError, match="instance id 40000"):
        PanopticEvaluator(kitti, mode="official").add(gt, pred)
    ev = PanopticEvaluator(kitti, mode="corrected")
    ev.add(gt, pred)
    r = ev.result()
    assert r.panoptic.per_class["car"].pq == 1.0 and r.mode == "corrected"
    # ids up to 65535 on both sides, several instances
    gt = np.concatenate([np.full(60, 10 | (65535 << 16)), np.full(60, 10 | (32768 << 16))]).astype(np.uint32)
    ev = PanopticEvaluator(kitti, mode="corrected")
    ev.add(gt, gt[::-1].copy())
    assert ev.result().panoptic.per_class["car"].tp == 2


def test_kitti_decoder_maps_through_learning_map(kitti):
    dec = KittiDecoder(kitti)
    labels = np.array([10, 252, 40, 60, 52, 1000, 10 | (5 << 16)], dtype=np.uint64)
    assert dec.classes(labels).tolist() == [1, 1, 9, 9, 0, 0, 1]
    assert dec.ids(labels).tolist() == [0, 0, 0, 0, 0, 0, 5]


def test_bad_inputs_raise_clear_errors(kitti):
    ev = PanopticEvaluator(kitti)
    with pytest.raises(ValueError, match="100 labels but pred has 99"):
        ev.add(np.zeros(100, np.uint32), np.zeros(99, np.uint32), frame="000001")
    with pytest.raises(ValueError, match="integers"):
        ev.add(np.zeros(3, np.float32), np.zeros(3, np.float32))
    with pytest.raises(ValueError, match=r"semantic train ids must lie in \[0, 20\)"):
        ev.add_train(np.array([25]), np.array([0]), np.array([1]), np.array([0]))
    with pytest.raises(ValueError, match="unknown scoring mode 'exact'"):
        PanopticEvaluator(kitti, mode="exact")
