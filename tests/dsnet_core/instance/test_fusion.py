import numpy as np
import pytest

from dsnet_core.instance.fusion import fuse

THINGS = range(1, 9)


def test_majority_vote_gives_each_instance_one_class_and_leaves_stuff_alone():
    sem = np.array([1, 1, 1, 4, 6, 7, 7, 6, 9, 9, 13, 1])
    inst = np.array(
        [1, 1, 1, 1, 2, 2, 2, 2, 0, 5, 0, 0]
    )  # a stray id on a stuff point; one unassigned car point
    xyz = np.arange(36, dtype=np.float32).reshape(12, 3)
    out = fuse(xyz, sem, inst, THINGS)
    assert out.semantic.tolist() == [1, 1, 1, 1, 6, 6, 6, 6, 9, 9, 13, 1]  # 6/7 tie goes to 6
    assert out.instance.tolist() == [1, 1, 1, 1, 2, 2, 2, 2, 0, 0, 0, 0]
    for i in (1, 2):
        assert len(np.unique(out.semantic[out.instance == i])) == 1
    stuff = ~np.isin(sem, list(THINGS))
    np.testing.assert_array_equal(out.semantic[stuff], sem[stuff])
    assert (out.instance[stuff] == 0).all()
    t = out.instances
    assert len(t) == 2
    assert t.id.tolist() == [1, 2] and t.class_id.tolist() == [1, 6] and t.n_points.tolist() == [4, 4]
    assert t.agreement.tolist() == [0.75, 0.5]
    np.testing.assert_allclose(t.centroid[0], xyz[:4].mean(axis=0))
    np.testing.assert_array_equal(t.box_min[1], xyz[4]) and np.testing.assert_array_equal(
        t.box_max[1], xyz[7]
    )
    assert np.isnan(t.confidence).all()


def test_confidence_is_mean_probability_of_the_winning_class():
    sem = np.array([1, 1, 4, 9])
    inst = np.array([3, 3, 3, 0])
    probs = np.zeros((4, 20), np.float16)
    probs[:, 1] = [0.9, 0.7, 0.2, 0.0]
    out = fuse(np.zeros((4, 3), np.float32), sem, inst, THINGS, probs)
    assert out.instances.confidence[0] == pytest.approx((0.9 + 0.7 + 0.2) / 3, abs=1e-3)
    assert out.semantic.tolist() == [1, 1, 1, 9]
    quantised = np.round(probs.astype(np.float32) * 255).astype(np.uint8)
    out8 = fuse(np.zeros((4, 3), np.float32), sem, inst, THINGS, quantised)
    assert out8.instances.confidence[0] == pytest.approx((0.9 + 0.7 + 0.2) / 3, abs=3e-3)


def test_no_instances_and_shape_errors():
    out = fuse(np.zeros((2, 3), np.float32), np.array([9, 10]), np.zeros(2, np.int64), THINGS)
    assert len(out.instances) == 0 and out.instance.tolist() == [0, 0]
    with pytest.raises(ValueError, match="disagree"):
        fuse(np.zeros((3, 3), np.float32), np.array([9, 10]), np.zeros(2, np.int64), THINGS)
