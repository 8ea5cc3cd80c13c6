import numpy as np
import pytest

from dsnet_core.review.confidence import frame_confidence


def test_terms_and_score():
    c = frame_confidence(
        max_prob=np.array([0.9, 0.7, np.nan, 0.8]),
        instance_points=np.array([100, 10, 50]),
        instance_agreement=np.array([1.0, 0.5, 0.8]),
        link_iou=np.array([0.9, np.nan, 0.7]),
    )
    assert c.semantic == pytest.approx(0.8)
    assert c.agreement == pytest.approx((100 + 5 + 40) / 160)
    assert c.size == pytest.approx(2 / 3)  # one of three instances has < 30 points
    assert c.stitch == pytest.approx(0.8)
    assert c.score == pytest.approx(0.8 * 145 / 160 * 2 / 3 * 0.8)
    assert c.n_instances == 3


def test_frame_without_instances_or_stitching_is_judged_by_semantics_alone():
    c = frame_confidence(np.full(5, 0.6, np.float16), np.zeros(0, int), np.zeros(0))
    assert (c.agreement, c.size, c.stitch) == (1.0, 1.0, 1.0) and c.score == pytest.approx(0.6, abs=1e-3)


def test_mismatched_instances_are_an_error():
    with pytest.raises(ValueError, match="differ"):
        frame_confidence(np.ones(3), np.ones(2), np.ones(3))
