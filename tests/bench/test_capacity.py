"""bench_capacity's table arithmetic on a worked example."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "bench"))

import bench_capacity  # noqa: E402


def _run(width: int, step: float, miou: float) -> dict:
    # start at 10 s; a slow first step (3 × step), then 4 steps of `step`; CPU time 90 % of wall
    wall = [10.0, 10.0 + 3 * step] + [10.0 + (3 + i) * step for i in range(1, 5)]
    cpu = [0.9 * w for w in wall]
    return {"width": width, "parameters": 1000 * width, "weights_bytes": 4_000_000 * width,
            "val_miou": miou, "wall": wall, "cpu": cpu}  # fmt: skip


def test_rows_give_medians_after_the_skip_rates_and_ratios_to_the_first_width():
    rows = bench_capacity.with_ratios(
        [bench_capacity.summarise(_run(4, 2.0, 0.1), 1), bench_capacity.summarise(_run(8, 5.0, 0.2), 1)]
    )
    a, b = rows
    assert a["steps"] == 5 and a["s_per_step"] == pytest.approx(2.0)  # the 6 s first step skipped
    assert a["cpu_s_per_step"] == pytest.approx(1.8) and a["weights_mb"] == pytest.approx(16.0)
    assert a["steps_per_hour"] == pytest.approx(1800.0)
    assert a["train_hours"] == pytest.approx(14.0 / 3600)  # every step counts, the first too
    assert a["miou_per_hour"] == pytest.approx(0.1 / (14.0 / 3600))
    assert (a["ratio"], a["cpu_ratio"]) == (1.0, 1.0)
    assert b["ratio"] == pytest.approx(2.5) and b["cpu_ratio"] == pytest.approx(2.5)
    table = bench_capacity.markdown(rows).splitlines()
    assert table[0].startswith("| width | parameters | weights MB | s/step | × w4 |")
    assert table[3] == "| 8 | 0.01 M | 32.0 | 5.00 | 2.50 | 4.50 | 2.50 | 720 | 0.2000 | 20.571 |"


def test_too_few_steps_for_the_skip_are_refused():
    with pytest.raises(ValueError, match="width 4: 5 steps, need more than --skip 5"):
        bench_capacity.summarise(_run(4, 2.0, 0.1), 5)
