"""Accumulator state saved to ``.npz`` bytes and restored merges to exactly the one-pass result."""

from __future__ import annotations

import numpy as np
import pytest

from dsnet_core.metrics.evaluator import PanopticEvaluator
from dsnet_core.metrics.state import restore_evaluator, state_from_bytes, state_to_bytes
from tests.dsnet_core.metrics.frames import raw_frame


@pytest.mark.parametrize("mode", ["official", "corrected"])
def test_saved_parts_merge_to_one_pass(kitti, mode):
    rng = np.random.default_rng(3)
    frames = [(seq, k, *raw_frame(rng, kitti, 5000, n_inst=4)) for seq in ("00", "01") for k in range(3)]
    one = PanopticEvaluator(kitti, min_points=20, mode=mode)
    parts = [PanopticEvaluator(kitti, min_points=20, mode=mode, keep_rows=False) for _ in range(3)]
    for i, (seq, k, gt, pred) in enumerate(frames):
        one.add(gt, pred, frame=str(k), sequence=seq)
        parts[i % 3].add(gt, pred, frame=str(k), sequence=seq)
    total = PanopticEvaluator(kitti, min_points=20, mode=mode)
    for part in parts:
        restored = restore_evaluator(kitti, state_from_bytes(state_to_bytes(part.state())))
        assert restored.result() == part.result()
        assert restored.result_by_sequence() == part.result_by_sequence()
        total.merge(restored)
    assert total.result() == one.result()
    assert total.result_by_sequence() == one.result_by_sequence()
    assert total.frames == 6 and total.result().lstq.n_tubes > 0


def test_state_refuses_another_label_map(kitti):
    from dsnet_core.labels import load_label_map

    state = PanopticEvaluator(kitti).state()
    with pytest.raises(ValueError, match="classes"):
        restore_evaluator(load_label_map("panoptic-nuscenes"), state)
