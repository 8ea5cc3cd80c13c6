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


def test_sums_at_points_equal_sums_in_the_given_order_bit_for_bit():
    rng = np.random.default_rng(3)
    p = np.concatenate([rng.normal(size=(400, 3)) * 0.3, rng.uniform(-8, 8, size=(300, 3))]).astype(
        np.float32
    )
    values = rng.normal(size=(2, len(p), 4))
    index = RadiusIndex(p, np.array([0.5, 2.0]), values)
    np.testing.assert_array_equal(index.sums_at_points(), index.sums(p.copy()))
    np.testing.assert_array_equal(radius_sums(p, p, np.array([0.5, 2.0]), values), index.sums(p.copy()))
    assert RadiusIndex(p[:0], np.array([1.0]), values[:1, :0]).sums_at_points().shape == (1, 0, 4)
