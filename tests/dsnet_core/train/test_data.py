import numpy as np

from dsnet_core.io.semantickitti import SemanticKittiReader
from dsnet_core.labels import load_label_map
from dsnet_core.train.data import augment, class_counts, data_fingerprint, load_sample, volume_refs
from tests.helpers.tiny_log import tiny_frame, write_tiny_log

LM = load_label_map("semantic-kitti")


def test_single_scan_sample(tmp_path):
    reader = SemanticKittiReader(write_tiny_log(tmp_path, frames=2))
    vols = volume_refs(reader, ["00"], scans=1)
    assert [[r.frame_id for r in v] for v in vols] == [["000000"], ["000001"]]
    s = load_sample(reader, vols[1], LM)
    pts, _ = tiny_frame(1)
    np.testing.assert_array_equal(s.points, pts)
    assert s.name == "00/000001"
    assert set(np.unique(s.sem)) == {1, 6, 9, 11, 13, 15}
    # instance keys only on things: car (train 1, id 1) and person (train 6, id 2)
    assert set(np.unique(s.inst[s.thing])) == {(1 << 32) | 1, (6 << 32) | 2}
    assert not s.thing[s.sem >= 9].any()


def test_volume_aligned_into_the_last_scan(tmp_path):
    reader = SemanticKittiReader(write_tiny_log(tmp_path, frames=3))
    vols = volume_refs(reader, ["00"], scans=2)
    assert [[r.frame_id for r in v] for v in vols][2] == ["000001", "000002"]
    s = load_sample(reader, vols[2], LM)
    p1, _ = tiny_frame(1)
    p2, _ = tiny_frame(2)
    assert len(s.points) == len(p1) + len(p2)
    assert s.frame_index.tolist() == [0] * len(p1) + [1] * len(p2)
    # poses translate by +0.5 m in x per frame: frame 1's points sit 0.5 m behind in frame 2's frame
    np.testing.assert_allclose(s.points[: len(p1), 0], p1[:, 0] - 0.5, atol=1e-5)
    np.testing.assert_array_equal(s.points[len(p1) :], p2)
    # the first frame has no history: it is its own volume (not duplicated)
    assert len(load_sample(reader, vols[0], LM).points) == len(tiny_frame(0)[0])


def test_augment_is_a_similarity_and_seeded():
    pts, _ = tiny_frame(0)
    a = augment(pts, np.random.default_rng(3))
    b = augment(pts, np.random.default_rng(3))
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(a[:, 3], pts[:, 3])
    # pairwise distances scale by one factor in [0.95, 1.05]
    d0 = np.linalg.norm(pts[1:, :3] - pts[:-1, :3], axis=1)
    d1 = np.linalg.norm(a[1:, :3] - a[:-1, :3], axis=1)
    ratio = d1 / d0
    assert 0.95 <= ratio.mean() <= 1.05 and ratio.std() < 1e-4


def test_class_counts_and_fingerprint(tmp_path):
    reader = SemanticKittiReader(write_tiny_log(tmp_path, frames=2))
    vols = volume_refs(reader, ["00"])
    counts = class_counts(reader, vols, LM)
    assert counts.sum() == 6000 and counts[9] == 2000 and counts[0] == 0
    fp = data_fingerprint(reader, vols)
    assert fp == data_fingerprint(reader, vols) and fp != data_fingerprint(reader, vols[:1])
