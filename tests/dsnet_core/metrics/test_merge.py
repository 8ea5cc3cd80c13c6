"""Merging partial accumulators gives exactly the one-pass result, for any split and order."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from dsnet_core.metrics.evaluator import PanopticEvaluator
from tests.dsnet_core.metrics.frames import raw_frame


def _frames(kitti, seed=0):
    rng = np.random.default_rng(seed)
    out = []
    for seq in ("00", "01"):
        for k in range(4):
            gt, pred = raw_frame(rng, kitti, 6000, n_inst=4)
            out.append((seq, f"{k:06d}", gt, pred))
    return out


@pytest.mark.parametrize("mode", ["official", "corrected"])
def test_merge_equals_one_pass_in_any_order(kitti, mode):
    frames = _frames(kitti)
    one = PanopticEvaluator(kitti, min_points=20, mode=mode)
    for seq, name, gt, pred in frames:
        one.add(gt, pred, frame=name, sequence=seq)
    expected = one.result()
    assert expected.lstq.n_tubes > 0 and expected.panoptic.pq > 0
    rng = np.random.default_rng(1)
    for trial in range(4):
        # frames of the same sequence land in different parts, each part in shuffled order
        parts = [PanopticEvaluator(kitti, min_points=20, mode=mode) for _ in range(3)]
        order = rng.permutation(len(frames))
        for i in order:
            seq, name, gt, pred = frames[i]
            parts[rng.integers(0, 3)].add(gt, pred, frame=name, sequence=seq)
        for perm in itertools.permutations(range(3)) if trial == 0 else [tuple(rng.permutation(3))]:
            total = PanopticEvaluator(kitti, min_points=20, mode=mode)
            for p in perm:
                total.merge(parts[p])
            got = total.result()
            assert got == expected
            assert sorted(total.rows, key=lambda r: (r.sequence, r.frame)) == one.rows


def test_merge_refuses_different_settings(kitti):
    a = PanopticEvaluator(kitti, mode="official")
    b = PanopticEvaluator(kitti, mode="corrected")
    with pytest.raises(ValueError, match="different"):
        a.merge(b)


def test_rows_report_each_frame(kitti):
    ev = PanopticEvaluator(kitti, min_points=1)
    gt = np.array([40] * 60 + [10 | (3 << 16)] * 40 + [0] * 5, dtype=np.uint32)
    pred = gt.copy()
    pred[:10] = 48  # 10 road points predicted sidewalk
    row = ev.add(gt, pred, frame="000007", sequence="08")
    assert (row.sequence, row.frame, row.n_points, row.n_valid) == ("08", "000007", 105, 100)
    assert (row.tp, row.fp, row.fn) == (2, 1, 0)  # road + car matched, sidewalk unmatched
    # classes seen: road (pq 50/60), car (1), sidewalk (0)
    assert row.pq == pytest.approx((50 / 60 + 1 + 0) / 3)
    assert row.miou == pytest.approx((50 / 60 + 1 + 0) / 3)
    assert ev.rows == [row] and set(row.to_dict()) >= {"sequence", "frame", "pq", "miou", "tp"}


def test_report_dict_has_the_issue_keys_and_no_nan(kitti):
    import json

    ev = PanopticEvaluator(kitti)
    ev.add(np.full(10, 40, np.uint32), np.full(10, 40, np.uint32))  # no thing tube: S_assoc undefined
    d = ev.result().to_dict()
    assert list(d)[:2] == ["mode", "pq"] and d["s_assoc"] is None and d["lstq"] is None
    assert d["per_class"]["road"] == {"pq": 1.0, "sq": 1.0, "rq": 1.0, "iou": 1.0} and d["frames"] == 1
    json.loads(json.dumps(d, allow_nan=False))


@pytest.mark.parametrize("mode", ["official", "corrected"])
def test_per_sequence_results_equal_scoring_each_sequence_alone(kitti, mode):
    frames = _frames(kitti, seed=2)
    both = PanopticEvaluator(kitti, min_points=20, mode=mode)
    alone = {"00": PanopticEvaluator(kitti, min_points=20, mode=mode)}
    alone["01"] = PanopticEvaluator(kitti, min_points=20, mode=mode)
    half = PanopticEvaluator(kitti, min_points=20, mode=mode)
    for k, (seq, name, gt, pred) in enumerate(frames):
        (both if k % 2 else half).add(gt, pred, frame=name, sequence=seq)
        alone[seq].add(gt, pred, frame=name, sequence=seq)
    per_seq = both.merge(half).result_by_sequence()
    assert list(per_seq) == ["00", "01"]
    for seq, ev in alone.items():
        assert per_seq[seq] == ev.result() and per_seq[seq].frames == 4
    assert both.result() != per_seq["00"]


def test_table_rows_for_classes_and_runs(kitti):
    from dsnet_core.metrics import class_rows, summary_row

    ev = PanopticEvaluator(kitti, min_points=1)
    ev.add(
        np.array([40] * 10 + [10 | (1 << 16)] * 5, np.uint32), np.array([40] * 15, np.uint32), sequence="08"
    )
    res = ev.result_by_sequence()["08"]
    rows = class_rows(res, sequence="08")
    assert len(rows) == 19 and rows[0]["class"] == "car" and rows[0]["thing"] is True
    road = next(r for r in rows if r["class"] == "road")
    assert (road["thing"], road["tp"], road["fn"], road["mode"], road["sequence"]) == (
        False,
        1,
        0,
        "official",
        "08",
    )
    assert road["iou"] == pytest.approx(10 / 15)
    run = summary_row(res, run="r1")
    assert "per_class" not in run and run["frames"] == 1 and run["run"] == "r1" and run["pq_things"] == 0.0
