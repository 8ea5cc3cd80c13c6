import numpy as np
import pytest
from pydantic import TypeAdapter, ValidationError
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from dsnet_core.instance.clustering import (
    CLUSTERERS,
    BFSClusterer,
    ClustererConfig,
    DBSCANClusterer,
    DynamicShiftClusterer,
    DynamicShiftConfig,
    HDBSCANClusterer,
    MeanShiftClusterer,
    get_clusterer,
)
from dsnet_core.instance.components import dbscan, radius_components
from dsnet_core.instance.shifting import BANDWIDTHS_4D, DynamicShift


def _objects(seed: int, k: int = 12, n: int = 1500):
    """Well separated objects: points on 1 m blobs, regressed centres tight around each centre."""
    rng = np.random.default_rng(seed)
    centres = np.stack([np.arange(k) * 6.0 - 30, rng.uniform(-10, 10, k), np.zeros(k)], axis=1)
    truth = rng.integers(0, k, n)
    xyz = (centres[truth] + rng.normal(size=(n, 3)) * [0.8, 0.8, 0.4]).astype(np.float32)
    reg = (centres[truth] + rng.normal(size=(n, 3)) * 0.1).astype(np.float32)
    return xyz, reg, truth


def _same_partition(a: np.ndarray, b: np.ndarray) -> bool:
    pairs = np.unique(np.stack([a, b], 1), axis=0)
    return len(pairs) == len(np.unique(a)) == len(np.unique(b))


def test_registry_and_discriminated_config():
    assert set(CLUSTERERS) == {"dynamic_shift", "meanshift", "dbscan", "hdbscan", "bfs"}
    adapter = TypeAdapter(ClustererConfig)
    cfg = adapter.validate_python({"kind": "dbscan", "eps": 0.5})
    assert isinstance(get_clusterer(cfg), DBSCANClusterer) and get_clusterer(cfg).eps == 0.5
    assert isinstance(get_clusterer(adapter.validate_python({"kind": "bfs"})), BFSClusterer)
    assert isinstance(get_clusterer(adapter.validate_python({"kind": "hdbscan"})), HDBSCANClusterer)
    assert get_clusterer(adapter.validate_python({"kind": "meanshift", "bandwidth": 2.0})).bandwidth == 2.0
    with pytest.raises(ValidationError, match="eps_typo"):
        adapter.validate_python({"kind": "dbscan", "eps_typo": 0.5})
    with pytest.raises(ValidationError, match="does not match any of the expected tags"):
        adapter.validate_python({"kind": "kmeans"})


def test_dynamic_shift_config_needs_weights_and_builds_from_state_dict():
    cfg = DynamicShiftConfig()
    with pytest.raises(ValueError, match="needs trained shifting weights"):
        get_clusterer(cfg)
    weights = DynamicShift.with_fixed_weights([0, 1, 0]).state_dict()
    clusterer = get_clusterer(cfg, weights)
    assert isinstance(clusterer, DynamicShiftClusterer)
    assert clusterer.module.bandwidths == (0.2, 1.7, 3.2) and clusterer.n_seeds == 10_000
    four_d = DynamicShiftConfig.for_4d(kernel="dense")
    assert four_d.bandwidths == BANDWIDTHS_4D and four_d.n_seeds == 20_000 and four_d.kernel == "dense"


@pytest.mark.parametrize(
    "clusterer",
    [
        MeanShiftClusterer(1.2),
        DBSCANClusterer(eps=0.4, min_samples=5),
        HDBSCANClusterer(min_cluster_size=20),
        BFSClusterer(radius=0.5),
        DynamicShiftClusterer(DynamicShift.with_fixed_weights([0, 1, 0]), n_seeds=400),
    ],
    ids=lambda c: type(c).__name__,
)
def test_every_clusterer_recovers_separated_objects(clusterer):
    xyz, reg, truth = _objects(0)
    ids = clusterer.cluster(xyz, reg, np.zeros((len(xyz), 32), np.float16))
    assert ids.dtype == np.int64 and ids.shape == truth.shape
    assert ids.min() == 1 and set(np.unique(ids)) == set(range(1, 13))
    assert _same_partition(ids, truth)


def test_dynamic_shift_non_seeds_take_nearest_seed_id():
    xyz, reg, _ = _objects(1, k=6, n=600)
    reg[:300] += np.float32(0.5)  # make the result depend on which points are seeds
    clusterer = DynamicShiftClusterer(DynamicShift.with_fixed_weights([1, 0, 0]), n_seeds=50)
    out = clusterer.run(xyz, reg, np.zeros((600, 32), np.float32))
    assert out.seeds.shape == (50,) and out.converged.shape == (50, 3)
    np.testing.assert_array_equal(clusterer.cluster(xyz, reg, np.zeros((600, 32), np.float32)), out.ids)
    _, nn = cKDTree(xyz[out.seeds]).query(xyz)
    np.testing.assert_array_equal(out.ids, out.ids[out.seeds][nn])


def test_dynamic_shift_needs_features_and_handles_tiny_inputs():
    clusterer = DynamicShiftClusterer(DynamicShift.with_fixed_weights([0, 1, 0]))
    xyz = np.zeros((3, 3), np.float32)
    with pytest.raises(ValueError, match="needs the per-point instance features"):
        clusterer.cluster(xyz, xyz, None)
    assert clusterer.cluster(xyz[:0], xyz[:0], np.zeros((0, 32), np.float32)).shape == (0,)
    assert clusterer.cluster(xyz[:1], xyz[:1], np.zeros((1, 32), np.float32)).tolist() == [1]


def test_noise_points_are_filled_from_nearest_or_left_unassigned():
    xyz, reg, _ = _objects(2, k=4, n=400)
    xyz = np.concatenate([xyz, [[100.0, 0, 0]]]).astype(np.float32)
    reg = np.concatenate([reg, [[100.0, 0, 0]]]).astype(np.float32)
    assert DBSCANClusterer(eps=0.4, min_samples=5, assign_noise=False).cluster(xyz, reg, None)[-1] == 0
    filled = DBSCANClusterer(eps=0.4, min_samples=5).cluster(xyz, reg, None)
    nearest = np.argmin(np.linalg.norm(xyz[:-1] - xyz[-1], axis=1))
    assert filled[-1] == filled[nearest] > 0


@pytest.mark.parametrize(("seed", "radius"), [(0, 0.2), (1, 0.35), (2, 0.6)])
def test_radius_components_match_scipy_graph(seed, radius):
    rng = np.random.default_rng(seed)
    x = (rng.uniform(-5, 5, size=(2000, 3)) * [1, 1, 0.2]).astype(np.float32)
    pairs = cKDTree(x.astype(np.float64)).query_pairs(radius, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(2000, 2000))
    _, ref = connected_components(graph, directed=False)
    got = radius_components(x, radius)
    assert _same_partition(got, ref)
    assert got[0] == 0 and got.max() == len(np.unique(ref)) - 1


@pytest.mark.parametrize(("seed", "eps", "min_samples"), [(0, 0.3, 5), (1, 0.5, 10), (2, 0.2, 3)])
def test_dbscan_matches_sklearn(seed, eps, min_samples):
    from sklearn.cluster import DBSCAN

    rng = np.random.default_rng(seed)
    centres = rng.uniform(-10, 10, size=(15, 3)) * [1, 1, 0.1]
    x = (centres[rng.integers(0, 15, 1500)] + rng.normal(size=(1500, 3)) * 0.25).astype(np.float32)
    ref = DBSCAN(eps=eps, min_samples=min_samples).fit(x.astype(np.float64))
    got = dbscan(x, eps, min_samples)
    np.testing.assert_array_equal(got == -1, ref.labels_ == -1)
    core = np.zeros(len(x), bool)
    core[ref.core_sample_indices_] = True
    assert _same_partition(got[core], ref.labels_[core])
    # border points may differ only where they are reachable from two clusters
    differ = ~core & (got >= 0)
    assert np.mean(_relabel(got, ref.labels_, core)[differ] != ref.labels_[differ]) < 0.01


def _relabel(got, ref, core):
    mapping = dict(zip(got[core], ref[core], strict=False))
    return np.array([mapping.get(g, -1) for g in got])
