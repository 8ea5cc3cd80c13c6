import numpy as np
import pytest

from dsnet_core.instance.fps import farthest_point_sampling


def naive_fps(points: np.ndarray, n: int) -> np.ndarray:
    p = points.astype(np.float64)
    dist = np.full(len(p), np.inf)
    out = [0]
    for _ in range(n - 1):
        dist = np.minimum(dist, ((p - p[out[-1]]) ** 2).sum(axis=1))
        out.append(int(np.argmax(dist)))
    return np.array(out, dtype=np.int64)


@pytest.mark.parametrize(("m", "n", "seed"), [(7, 3, 0), (300, 100, 1), (2500, 700, 2), (5000, 4999, 3)])
def test_matches_naive_reference(m, n, seed):
    rng = np.random.default_rng(seed)
    pts = (rng.normal(size=(m, 3)) * [20.0, 20.0, 1.0]).astype(np.float32)
    got = farthest_point_sampling(pts, n)
    assert got.dtype == np.int64 and got.shape == (n,)
    np.testing.assert_array_equal(got, naive_fps(pts, n))


def test_clustered_points_and_duplicates_match_naive():
    rng = np.random.default_rng(4)
    centres = rng.uniform(-40, 40, size=(12, 3)).astype(np.float32)
    pts = centres[rng.integers(0, 12, 1500)] + rng.normal(size=(1500, 3)).astype(np.float32) * 0.3
    pts[100:110] = pts[5]  # exact duplicates
    np.testing.assert_array_equal(farthest_point_sampling(pts, 400), naive_fps(pts, 400))


def test_all_points_when_fewer_than_requested():
    pts = np.zeros((5, 3), np.float32)
    np.testing.assert_array_equal(farthest_point_sampling(pts, 10), np.arange(5))
    np.testing.assert_array_equal(farthest_point_sampling(pts, 5), np.arange(5))
    assert farthest_point_sampling(np.zeros((0, 3), np.float32), 10).shape == (0,)


def test_picks_are_distinct_and_start_at_zero():
    rng = np.random.default_rng(5)
    pts = rng.uniform(-50, 50, size=(20000, 3)).astype(np.float32)
    got = farthest_point_sampling(pts, 3000)
    assert got[0] == 0
    assert np.unique(got).size == 3000


def test_rejects_bad_shape():
    with pytest.raises(ValueError, match=r"shape \(M, 3\)"):
        farthest_point_sampling(np.zeros((4, 2), np.float32), 2)


def test_nearest_sample_is_the_brute_force_nearest_earliest_on_ties():
    from dsnet_core.instance.fps import sample_with_nearest

    rng = np.random.default_rng(5)
    pts = np.concatenate([rng.normal(size=(700, 3)), rng.integers(0, 4, size=(300, 3))]).astype(np.float32)
    samples, nearest = sample_with_nearest(pts, 90)
    assert np.array_equal(samples, farthest_point_sampling(pts, 90))
    p64 = pts.astype(np.float64)
    d2 = ((p64[:, None, :] - p64[samples][None, :, :]) ** 2).sum(-1)
    assert np.array_equal(nearest, np.argmin(d2, axis=1))  # argmin: the first (earliest) of equals
    all_s, all_n = sample_with_nearest(pts[:50], 60)
    assert np.array_equal(all_s, np.arange(50)) and np.array_equal(all_n, np.arange(50))
