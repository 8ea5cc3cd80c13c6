import numpy as np

from dsnet_core.oracle import box_centres, noisy_centres, oracle_features
from dsnet_core.toyscene import make_scene


def test_box_centres_are_tight_box_centres_not_centroids():
    xyz = np.array([[0, 0, 0], [1, 0, 0], [4, 2, 1], [9, 9, 9]], np.float32)
    inst = np.array([1, 1, 1, 0])
    c = box_centres(xyz, inst)
    np.testing.assert_array_equal(c[:3], np.tile([2.0, 1.0, 0.5], (3, 1)))
    np.testing.assert_array_equal(c[3], xyz[3])


def test_noise_is_elongated_along_the_ray_and_grows_with_range():
    rng = np.random.default_rng(0)
    n = 40_000
    rho = np.where(np.arange(n) < n // 2, 10.0, 40.0)
    phi = rng.uniform(-np.pi, np.pi, n)
    xyz = np.stack([rho * np.cos(phi), rho * np.sin(phi), np.zeros(n)], 1).astype(np.float32)
    inst = np.arange(n) + 1  # one point per instance: the bias is per-point noise here too
    err = noisy_centres(xyz, xyz, inst, seed=1, under_fraction=0.0).astype(np.float64) - xyz
    ray = xyz / np.linalg.norm(xyz, axis=1, keepdims=True)
    radial = np.einsum("ij,ij->i", err, ray)
    tangential = np.linalg.norm(err - radial[:, None] * ray, axis=1)
    near, far = slice(0, n // 2), slice(n // 2, n)
    assert radial[far].std() > 2.0 * radial[near].std()
    assert radial[near].std() > 1.2 * tangential[near].std()
    assert radial[far].std() > 1.5 * tangential[far].std()


def test_toy_scene_is_deterministic_and_features_are_32d():
    a, b = make_scene(3, n_objects=8), make_scene(3, n_objects=8)
    np.testing.assert_array_equal(a.xyz, b.xyz)
    np.testing.assert_array_equal(a.instance, b.instance)
    th = a.instance > 0
    assert set(np.unique(a.semantic[th])) <= {1, 4, 6, 7} and (a.semantic[~th] >= 9).all()
    f = oracle_features(a.xyz[th], box_centres(a.xyz[th], a.instance[th]), a.semantic[th])
    assert f.shape == (th.sum(), 32) and f.dtype == np.float32 and np.isfinite(f).all()
