"""Oracle helpers: box centres, ray-shaped noise, radius components, windows."""

import numpy as np

from dsnet_core.oracle4d import CentreNoise, box_centres, grid_components, noisy, windows


def test_box_centres_are_tight_box_centres_not_centroids():
    xyz = np.array([[0, 0, 0], [1, 0, 0], [4, 2, 0], [10, 10, 10]], float)
    c = box_centres(xyz, np.array([1, 1, 1, 2]))
    np.testing.assert_allclose(c, [[2, 1, 0]] * 3 + [[10, 10, 10]])


def test_noise_is_elongated_along_the_ray_and_grows_with_range():
    rng = np.random.default_rng(0)
    xyz = np.tile([[20.0, 0.0, 0.0]], (20000, 1))
    d = noisy(np.zeros_like(xyz), xyz, rng, CentreNoise(base=0.03, per_metre=0.004, ray_factor=2.5))
    sigma = 0.03 + 0.004 * 20
    np.testing.assert_allclose(d.std(0), [2.5 * sigma, sigma, sigma], rtol=0.03)
    far = noisy(np.zeros_like(xyz), 2 * xyz, rng, CentreNoise())
    assert far[:, 1].std() > 1.5 * d[:, 1].std()


def test_grid_components():
    rng = np.random.default_rng(1)
    a = rng.normal(0, 0.05, (50, 3))
    b = rng.normal(0, 0.05, (30, 3)) + np.array([3.0, 0, 0])
    outlier = np.array([[1.2, 0, 0]])
    ids = grid_components(np.concatenate([a, b, outlier]), cell=0.3, min_size=5)
    assert set(ids[:50].tolist()) == {1} and set(ids[50:80].tolist()) == {2}
    assert ids[80] == 1  # the lone outlier joins the nearest large component
    assert grid_components(np.zeros((0, 3))).shape == (0,)
    # adjacency: same or 26-neighbour cells; two cells apart is not connected
    ids = grid_components(np.array([[0.05, 0.05, 0.05], [0.35, 0.35, 0.35], [0.95, 0.05, 0.05]]), 0.3, 1)
    assert ids.tolist() == [1, 1, 2]


def test_windows():
    assert windows(7, 3, 2) == [[0, 1, 2], [2, 3, 4], [4, 5, 6]]
    assert windows(8, 3, 2) == [[0, 1, 2], [2, 3, 4], [4, 5, 6], [5, 6, 7]]
    assert windows(2, 4, 3) == [[0, 1]]
    assert windows(3, 1, 1) == [[0], [1], [2]]
