import numpy as np
import pytest

from dsnet_core.instance.radius import RadiusIndex, radius_sums


def _brute(q, p, radii, values):
    d2 = ((q[:, None, :] - p[None, :, :]) ** 2).sum(-1)
    return np.stack([(d2 <= r * r).astype(np.float64) @ values[j] for j, r in enumerate(radii)])


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_matches_brute_force_with_clustered_and_spread_points(dtype):
    rng = np.random.default_rng(0)
    centres = rng.uniform(-20, 20, size=(10, 3))
    p = np.concatenate(
        [
            centres[rng.integers(0, 10, 1500)] + rng.normal(size=(1500, 3)) * 0.05,
            rng.uniform(-25, 25, size=(500, 3)),
        ]
    ).astype(dtype)
    q = np.concatenate([p[:300], rng.uniform(-25, 25, size=(200, 3)).astype(dtype)])
    radii = np.array([0.2, 1.7, 3.2])
    values = rng.normal(size=(3, len(p), 2))
    np.testing.assert_allclose(radius_sums(q, p, radii, values), _brute(q, p, radii, values), atol=1e-9)


def test_boundary_is_included_and_index_is_reusable():
    g = np.stack(np.meshgrid(*[np.arange(5) * 0.5] * 3, indexing="ij"), -1).reshape(-1, 3)
    index = RadiusIndex(g, np.array([0.5]), np.ones((1, len(g), 1)))
    counts = index.sums(g)[0, :, 0]
    assert counts[0] == 4  # the corner, and its 3 neighbours at exactly 0.5 m
    assert counts.max() == 7  # an inner point: itself and 6 face neighbours
    assert index.sums(g[:1] + 10.0)[0, 0, 0] == 0


def test_rejects_bad_inputs():
    p = np.zeros((3, 3))
    with pytest.raises(ValueError, match="ascending"):
        radius_sums(p, p, np.array([2.0, 1.0]), np.ones((2, 3, 1)))
    with pytest.raises(ValueError, match="share a dtype"):
        radius_sums(p.astype(np.float32), p, np.array([1.0]), np.ones((1, 3, 1)))
    with pytest.raises(ValueError, match="NaN or inf"):
        radius_sums(p, np.full((3, 3), np.nan), np.array([1.0]), np.ones((1, 3, 1)))


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_dual_tree_sums_at_points_equal_one_walk_per_point(dtype):
    rng = np.random.default_rng(3)
    p = np.concatenate(
        [
            rng.normal(size=(400, 3)) * 0.3,
            rng.uniform(-8, 8, size=(300, 3)),
            np.repeat(rng.uniform(-3, 3, size=(5, 3)), 40, axis=0),  # coincident points: big leaves
        ]
    ).astype(dtype)
    radii = np.array([0.05, 0.5, 2.0, 40.0])  # the last radius holds every pair
    values = rng.normal(size=(4, len(p), 3))
    index = RadiusIndex(p, radii, values)
    walk = index.sums(p.copy())
    np.testing.assert_allclose(index.sums_at_points(), walk, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(radius_sums(p, p, radii, values), _brute(p, p, radii, values), atol=1e-9)
    ones = np.ones((4, len(p), 1))  # counts: exact whatever the order of the additions
    np.testing.assert_array_equal(RadiusIndex(p, radii, ones).sums_at_points(), _brute(p, p, radii, ones))
    one = RadiusIndex(p[:1], radii, values[:, :1])
    np.testing.assert_array_equal(one.sums_at_points(), values[:, :1])
    assert RadiusIndex(p[:0], np.array([1.0]), values[:1, :0]).sums_at_points().shape == (1, 0, 3)
