"""bench_transfer's confusion table and bench_giveaways' measures, on worked examples."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "bench"))

import _present  # noqa: E402
import _stability  # noqa: E402
import bench_giveaways  # noqa: E402
import bench_transfer  # noqa: E402

NAMES = ["unlabeled", "car", "building", "fence"]


def test_confusions_give_shares_of_each_ground_truth_class():
    conf = np.zeros((4, 4), np.int64)  # conf[pred, gt]
    conf[2, 2], conf[3, 2], conf[0, 2] = 20, 70, 10  # building: 20 right, 70 fence, 10 unlabelled
    conf[1, 1] = 50  # car: all right
    out = bench_transfer.confusions(conf, NAMES, top=2)
    assert set(out) == {"car", "building"}  # fence has no ground-truth points
    b = out["building"]
    assert b["points"] == 100 and b["right"] == 0.2
    assert b["wrong"] == [("fence", 0.7), ("unlabeled", 0.1)]
    assert out["car"] == {"points": 50, "right": 1.0, "wrong": []}


def test_markdown_lists_means_per_class_iou_and_confusions():
    conf = np.zeros((4, 4), np.int64)
    conf[3, 2], conf[2, 2] = 8, 2
    scores = {
        "miou": 0.5, "pq": 0.4, "pq_things": 0.3, "pq_stuff": 0.2, "lstq": 0.6,
        "class_iou": {"car": 1.0, "building": 0.2, "fence": 0.0},
        "confusion": conf.tolist(), "class_names": NAMES,
    }  # fmt: skip
    row = {"k1": {"scores": scores, "s_per_frame": {"infer": 0.5}}}
    md = bench_transfer.markdown({"m": {"seeds": row, "styles": row, bench_transfer.OTHER: row}})
    assert "| m | k1 | 0.500 | 0.400 | 0.500 | 0.400 | 0.600 |" in md  # synth means, other generator
    assert "| m | seeds | k1 | – | 0.20 | – |" in md  # car and fence have no ground-truth points
    assert "| building | **20** · fence 80 | **20** · fence 80 | **20** · fence 80 |" in md


def test_separability_is_a_folded_rank_probability():
    a, b = np.array([1.0, 2.0, 3.0]), np.array([4.0, 5.0])
    assert bench_giveaways.separability(a, b) == 1.0
    assert bench_giveaways.separability(np.array([1.0, 2.0]), np.array([2.0, 1.0])) == 0.5
    assert bench_giveaways.separability(np.array([1.0, 3.0]), np.array([2.0, np.nan])) == 0.5
    assert np.isnan(bench_giveaways.separability(np.array([]), b))


def test_object_rows_measure_a_wall_and_a_thin_fence():
    rng = np.random.default_rng(0)
    ground = np.stack([rng.uniform(-10, 10, 4000), rng.uniform(-10, 10, 4000), np.zeros(4000)], axis=1)
    wall = np.stack([rng.uniform(0, 6, 600), np.full(600, 5.0), rng.uniform(0, 4, 600)], axis=1)
    fence = np.stack([rng.uniform(-8, -4, 300), np.full(300, 5.0), rng.uniform(0, 1.2, 300)], axis=1)
    xyz = np.concatenate([ground, wall, fence])
    sem = np.concatenate([np.full(4000, 72), np.full(600, 50), np.full(300, 51)])
    rows = bench_giveaways.object_rows(
        xyz, np.full(len(xyz), 0.3), sem, np.zeros(len(xyz), np.int64), bench_giveaways.ground_model(xyz, sem)
    )
    by = {r["class"]: r for r in rows}
    assert set(by) == {"building", "fence"}
    assert 3.8 < by["building"]["top"] < 4.0 and 1.1 < by["fence"]["top"] < 1.2
    assert 5.0 < by["building"]["length"] < 5.6 and by["fence"]["thickness"] < 0.01
    assert by["fence"]["on_terrain"] == 1.0 and by["building"]["texture"] < 0.01


def test_present_mean_averages_the_classes_with_ground_truth_points():
    conf = np.zeros((4, 4), np.int64)  # conf[pred, gt]; fence has no ground-truth points
    conf[1, 1], conf[2, 2], conf[3, 2] = 10, 6, 4
    conf[3, 0] = 5  # predictions on unlabelled points: no ground truth for any class
    points = _present.gt_points(conf, NAMES)
    assert points == {"car": 10, "building": 10, "fence": 0}
    iou = {"car": 0.9, "building": 0.5, "fence": 0.0}
    assert _present.present_classes(points) == ["car", "building"]
    assert _present.present_mean(iou, points) == pytest.approx(0.7)  # official mean: 1.4 / 3
    scores = {
        "class_iou": iou, "class_pq": {"car": 0.8, "building": 0.2, "fence": 0.0}, "class_things": ["car"],
        "confusion": conf.tolist(), "class_names": NAMES,
    }  # fmt: skip
    out = _present.present_scores(scores)
    assert out["absent"] == ["fence"]
    assert out["miou_present"] == pytest.approx(0.7) and out["pq_present"] == pytest.approx(0.5)
    assert out["pq_things_present"] == pytest.approx(0.8) and out["pq_stuff_present"] == pytest.approx(0.2)
    assert np.isnan(_present.present_mean(iou, {"car": 0, "building": 0}))
    with pytest.raises(KeyError, match="building"):
        _present.present_mean({"car": 0.9}, points)


def test_flip_counts_count_changed_points_by_reference_class():
    ref = np.array([1, 1, 1, 2, 2, 3], np.uint8)
    new = np.array([1, 2, 1, 2, 1, 3], np.uint8)
    points, changed = _stability.flip_counts(ref, new, 4)
    assert points.tolist() == [0, 3, 2, 1] and changed.tolist() == [0, 1, 1, 0]
    with pytest.raises(ValueError, match="6 and 5 points"):
        _stability.flip_counts(ref, new[:5], 4)


def test_jitter_moves_coordinates_within_the_bound_and_keeps_remission():
    scan = np.array([[1.0, 2.0, 3.0, 0.25], [10.0, -20.0, 0.5, 0.75]] * 500, np.float32)
    out = _stability.jitter_points(scan, 5.0, np.random.default_rng(0))
    step = out[:, :3].astype(np.float64) - scan[:, :3]
    assert np.abs(step).max() <= 0.005 + 1e-6 and np.abs(step).max() > 0.004
    assert abs(step.mean()) < 5e-4  # uniform, centred
    assert np.array_equal(out[:, 3], scan[:, 3])
    again = _stability.jitter_points(scan, 5.0, np.random.default_rng(0))
    assert np.array_equal(out, again)  # seeded
    # rounding a ±5 mm jitter of 1 cm-rounded coordinates to 1 cm gives them back
    cm = np.round(scan[:, :3] * 100) / 100
    moved = _stability.jitter_points(np.c_[cm, scan[:, 3]], 4.9, np.random.default_rng(1))
    assert np.array_equal(np.round(moved[:, :3] * 100) / 100, cm)


def test_markdown_shows_present_means_flips_and_before_refine():
    conf = np.zeros((4, 4), np.int64)
    conf[1, 1], conf[2, 2] = 10, 10  # fence absent
    scores = {
        "miou": 0.5, "pq": 0.4, "pq_things": 0.3, "pq_stuff": 0.2, "lstq": 0.6,
        "class_iou": {"car": 1.0, "building": 0.5, "fence": 0.0},
        "class_pq": {"car": 0.9, "building": 0.3, "fence": 0.0}, "class_things": ["car"],
        "confusion": conf.tolist(), "class_names": NAMES,
    }  # fmt: skip
    row = {
        "k1": {
            "scores": scores,
            "scores_before_refine": scores,
            "s_per_frame": {"infer": 0.5},
            "stability": {"share": 0.0123},
        }
    }
    md = bench_transfer.markdown({"m": {"seeds": row, bench_transfer.PANDASET: row}})
    # mIoU, present mIoU, PQ, present PQ, PQ^Th, PQ^St, LSTQ, flip %
    assert "| m | pandaset | k1 | 0.500 | 0.750 | 0.400 | 0.600 | 0.300 | 0.200 | 0.600 | 1.23 | 0.50 |" in md
    before = "| m | pandaset | k1 | 0.500 | 0.750 | 0.400 | 0.600 | 0.300 | 0.200 | 0.600 |\n"
    assert before in md  # the before-refine table has no flip or s/frame columns
    assert "| m | k1 | 0.500 | 0.400 | – | – | – | 0.500 | 0.750 | 0.400 | 0.600 | 0.600 | 1.23 |" in md
    assert "| m | pandaset | k1 | 1.00 | 0.50 | – |" in md  # IoU per class, fence absent
    assert "| m | pandaset | k1 | 0.90 | 0.30 | – |" in md  # PQ per class


def test_top_margin_and_cell_moves():
    probs = np.array([[200, 50, 5], [100, 100, 55], [0, 0, 255]], np.uint8)
    assert _stability.top_margin(probs) == pytest.approx([150 / 255, 0.0, 1.0])
    from dsnet_core.model.grid import CylinderGrid

    grid = CylinderGrid()  # ρ cells of 47 m / 480 ≈ 9.8 cm from 3 m
    a = np.array([[10.0, 0.0, 0.0, 0.5], [10.06, 0.0, 0.0, 0.5]], np.float32)  # ρ cells 71 and 72
    b = a + np.array([0.004, 0.0, 0.0, 0.0], np.float32)
    assert _stability.cell_moved(a, b, grid).tolist() == [False, False]
    b[1, 0] = 10.04  # across the boundary at 3 + 72 · 47 / 480 = 10.05 m
    assert _stability.cell_moved(a, b, grid).tolist() == [False, True]


def test_make_cell_returns_the_log_and_its_sequences_when_reused(tmp_path):
    import json

    out = tmp_path / "seeds"
    out.mkdir()
    seed, first, setups = bench_transfer.CELLS["seeds"]
    want = {"seed": seed, "first": first, "setups": setups, "frames": bench_transfer.FRAMES}
    (out / "bench_cell.json").write_text(json.dumps(want))  # a current cell: nothing generated
    assert bench_transfer.make_cell(tmp_path, "seeds") == (out, None)
