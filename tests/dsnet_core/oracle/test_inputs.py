import numpy as np

from dsnet_core.oracle.inputs import box_centres, noisy_centres, oracle_inputs


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


def test_oracle_inputs_and_features():
    rng = np.random.default_rng(2)
    xyz = rng.uniform(-30, 30, size=(3000, 3)).astype(np.float32)
    sem = rng.choice([1, 6, 9, 13], size=3000)
    inst = np.where(sem < 9, rng.integers(1, 20, 3000), 0)
    o = oracle_inputs(xyz, sem, inst, range(1, 9), noise_seed=0)
    assert o.thing.tolist() == (sem < 9).tolist()
    m = int(o.thing.sum())
    assert o.centres.shape == o.gt_centres.shape == (m, 3)
    assert o.features.shape == (m, 32) and o.features.dtype == np.float32 and np.isfinite(o.features).all()
    # instance ids are per class: the same id in two classes is two boxes
    key = sem[o.thing] * 65536 + inst[o.thing]
    np.testing.assert_array_equal(o.gt_centres, box_centres(xyz[o.thing], key))
    np.testing.assert_array_equal(o.features[:, :8].argmax(axis=1) + 1, sem[o.thing])
