"""bench_transfer's confusion table and bench_giveaways' measures, on worked examples."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "bench"))

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
    assert "| m | seeds | k1 | 1.00 | 0.20 | 0.00 |" in md
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
