import numpy as np
import pytest
from sklearn.cluster import MeanShift

from dsnet_core.instance.meanshift import bin_seeds, cluster_seeds, mean_shift


def _blobs(seed: int, n: int = 2000, k: int = 25, spread: float = 0.3) -> np.ndarray:
    rng = np.random.default_rng(seed)
    centres = rng.uniform(-30, 30, size=(k, 3)) * [1.0, 1.0, 0.05]
    return (centres[rng.integers(0, k, n)] + rng.normal(size=(n, 3)) * spread).astype(np.float32)


@pytest.mark.parametrize(("seed", "spread", "bandwidth"), [(0, 0.05, 0.65), (1, 0.3, 0.65), (2, 0.8, 1.2)])
def test_same_clusters_as_sklearn(seed, spread, bandwidth):
    x = _blobs(seed, spread=spread)
    ref = MeanShift(bandwidth=bandwidth, bin_seeding=True).fit(x)
    labels, centres = mean_shift(x, bandwidth)
    # same centres in the same (intensity) order, hence identical labels
    np.testing.assert_array_equal(labels, ref.labels_)
    np.testing.assert_allclose(centres, ref.cluster_centers_, atol=1e-4)


def test_bin_seeds_fall_back_to_points_when_every_point_has_its_own_bin():
    x = np.array([[0, 0, 0], [5, 0, 0], [0, 5, 0]], np.float32)
    np.testing.assert_array_equal(bin_seeds(x, 0.65), x)
    y = np.array([[0, 0, 0], [0.1, 0, 0], [5, 0, 0]], np.float32)
    assert bin_seeds(y, 0.65).shape == (2, 3)


def test_cluster_seeds_ids_start_at_one_largest_first():
    x = np.concatenate([np.zeros((30, 3)), np.full((10, 3), 5.0), np.full((20, 3), -5.0)]).astype(np.float32)
    ids = cluster_seeds(x)
    assert ids.tolist() == [1] * 30 + [3] * 10 + [2] * 20
    assert cluster_seeds(np.zeros((0, 3), np.float32)).shape == (0,)


def test_unique_rows_equal_numpys_row_unique():
    from dsnet_core.instance.meanshift import _unique_rows

    rng = np.random.default_rng(4)
    for cells in (
        rng.integers(-50, 50, size=(3000, 3)),
        np.zeros((5, 3), np.int64),
        rng.integers(-2, 2, size=(1, 3)),
    ):
        np.testing.assert_array_equal(_unique_rows(cells), np.unique(cells, axis=0))
    assert _unique_rows(np.zeros((0, 3), np.int64)).shape == (0, 3)
