import numpy as np

from dsnet_core.instance.kdtree import build_kdtree, leaves


def _clouds():
    rng = np.random.default_rng(0)
    yield rng.normal(size=(1000, 3)).astype(np.float32)
    yield np.repeat(rng.uniform(-5, 5, size=(40, 3)), 30, axis=0)  # many ties and coincident points
    yield np.zeros((300, 3))  # all coincident: one leaf
    yield rng.integers(0, 3, size=(500, 3)).astype(np.float64)


def test_children_split_their_parent_at_the_median_of_its_widest_axis():
    for pts in _clouds():
        order, start, end, left = build_kdtree(pts, 16)
        assert np.array_equal(np.sort(order), np.arange(len(pts)))
        for node in np.flatnonzero(left >= 0):
            a, b = left[node], left[node] + 1
            assert (start[a], end[a], start[b], end[b]) == (
                start[node],
                start[a] + (end[node] - start[node]) // 2,
                end[a],
                end[node],
            )
            sub = pts[order[start[node] : end[node]]]
            axis = int(np.argmax(sub.max(0) - sub.min(0)))
            lo, hi = pts[order[start[a] : end[a]], axis], pts[order[start[b] : end[b]], axis]
            assert lo.max() <= hi.min()
        for leaf in np.flatnonzero(left < 0):
            sub = pts[order[start[leaf] : end[leaf]]]
            assert end[leaf] - start[leaf] <= 16 or np.all(sub == sub[0])


def test_leaves_cover_the_points_in_order():
    for pts in _clouds():
        order, bounds = leaves(pts, 8)
        assert bounds[0] == 0 and bounds[-1] == len(pts) and np.all(np.diff(bounds) > 0)
        assert np.array_equal(np.sort(order), np.arange(len(pts)))
