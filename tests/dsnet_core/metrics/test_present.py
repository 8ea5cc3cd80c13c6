"""Means over the classes present (metric ``present``): golden values on a hand-made frame, the same
per-class values as the official means, and saved states from before the registry refused."""

from __future__ import annotations

import math

import numpy as np
import pytest

from dsnet_core.metrics.evaluator import PanopticEvaluator
from dsnet_core.metrics.present import present_class_means
from dsnet_core.metrics.scoring import restore_scorer
from dsnet_core.metrics.state import restore_evaluator, state_from_bytes, state_to_bytes

CAR, ROAD, SIDEWALK, BUILDING, VEGETATION = 1, 9, 11, 13, 15


def _frame() -> tuple[np.ndarray, ...]:
    """Ground truth: 100 car (instance 1), 200 road, 100 building points: 3 of the 19 classes.
    Prediction: the car right, 150 road + 50 sidewalk, 80 building + 20 vegetation."""
    gt_sem = np.repeat([CAR, ROAD, BUILDING], [100, 200, 100])
    gt_inst = np.where(gt_sem == CAR, 1, 0)
    pred_sem = np.repeat([CAR, ROAD, SIDEWALK, BUILDING, VEGETATION], [100, 150, 50, 80, 20])
    return gt_sem, gt_inst, pred_sem, gt_inst.copy()


@pytest.fixture
def scored(kitti):
    ev = PanopticEvaluator(kitti, min_points=10)
    row = ev.add_train(*_frame(), frame="000000", sequence="00")
    return ev, row


def test_golden_values_by_hand(scored):
    ev, row = scored
    v = ev.result().values
    # IoU: car 100/100, road 150/200, building 80/100; PQ: each one match (IoU 1, 0.75, 0.8), RQ 1
    assert v["present_classes"] == 3
    assert v["miou_present"] == pytest.approx((1 + 0.75 + 0.8) / 3, abs=1e-12)
    assert v["pq_present"] == pytest.approx(0.85, abs=1e-12)
    assert v["sq_present"] == pytest.approx(0.85, abs=1e-12) and v["rq_present"] == pytest.approx(
        1.0, abs=1e-12
    )
    # the official means divide the same sums by all 19 classes (absent ones, sidewalk and
    # vegetation with their false positives included, count 0)
    assert v["miou"] == pytest.approx(2.55 / 19, abs=1e-12) and v["pq"] == pytest.approx(2.55 / 19, abs=1e-12)
    assert row.values["miou_present"] == pytest.approx(0.85, abs=1e-12)
    assert row.values["pq_present"] == pytest.approx(0.85, abs=1e-12)
    gt_points = {name: c["gt_points"] for name, c in ev.result().classes.items() if c["gt_points"]}
    assert gt_points == {"car": 100, "road": 200, "building": 100}


def test_present_means_are_the_official_per_class_values_averaged(kitti):
    from tests.dsnet_core.metrics.frames import raw_frame

    rng = np.random.default_rng(5)
    ev = PanopticEvaluator(kitti, min_points=20)
    to_train = np.vectorize(lambda raw: kitti.learning_map.get(int(raw), 0))
    for k in range(3):
        gt, pred = raw_frame(rng, kitti, 4000, n_inst=3)
        keep = to_train(gt & 0xFFFF) < 12  # ground truth of classes 12..19 left out: absent
        ev.add(gt[keep], pred[keep], frame=str(k), sequence="00")
    res = ev.result()
    present = [n for n, c in res.classes.items() if c["gt_points"] > 0]
    assert 0 < len(present) < 19
    per = res.panoptic.per_class
    for key, attr in (
        ("miou_present", "iou"),
        ("pq_present", "pq"),
        ("sq_present", "sq"),
        ("rq_present", "rq"),
    ):
        assert res.values[key] == pytest.approx(np.mean([getattr(per[n], attr) for n in present]), abs=1e-12)
    assert res.values["miou_present"] >= res.values["miou"]


def test_plain_function_by_name_and_by_array():
    got = present_class_means(
        {"car": 1.0, "road": 0.75, "building": 0.8, "sidewalk": 0.0},
        {"car": 100, "road": 200, "building": 100},
    )
    assert got == pytest.approx({"miou_present": 0.85, "present_classes": 3.0}, abs=1e-12)
    arr = present_class_means(np.array([0.5, 0.2, 0.0]), np.array([3, 0, 0]), pq=np.array([0.4, 0.0, 0.0]))
    assert arr["miou_present"] == 0.5 and arr["pq_present"] == 0.4 and arr["present_classes"] == 1
    none = present_class_means(np.zeros(2), np.zeros(2))
    assert math.isnan(none["miou_present"]) and none["present_classes"] == 0
    with pytest.raises(ValueError, match="gt_counts has 1 values, iou_per_class 2"):
        present_class_means(np.zeros(2), np.zeros(1))


def test_state_round_trip_keeps_present_means(scored, kitti):
    ev, _ = scored
    back = restore_evaluator(kitti, state_from_bytes(state_to_bytes(ev.state())))
    assert back.result().values == ev.result().values


def test_a_state_saved_before_the_registry_is_refused_in_one_line(kitti):
    old = {  # the layout 1 keys (meta, mode, ignore, pq_*, seqs): no "format"
        "meta": np.array([50, 0]),
        "mode": np.array("official"),
        "ignore": np.array([0]),
        "pq_conf": np.zeros((20, 20), np.int64),
        "seqs": np.array([], dtype=str),
    }
    with pytest.raises(ValueError, match=r"layout 1, this version reads layout 2 .* score the frames again"):
        restore_evaluator(kitti, old)
    with pytest.raises(ValueError, match="layout 1"):
        restore_scorer(PanopticEvaluator(kitti), old)
