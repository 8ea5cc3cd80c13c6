"""D-PLS prior files: both layouts, ``.label`` and ``.npy`` round trips, and every refusal names the file."""

from __future__ import annotations

import numpy as np
import pytest

from dsnet_core.errors import PriorFormatError
from dsnet_core.io.prior import find_prior, prior_classes, read_prior
from dsnet_core.labels import load_label_map

LM = load_label_map("semantic-kitti")


def _labels(train: np.ndarray, instance: int = 0) -> np.ndarray:
    return (LM.to_raw(train).astype(np.uint32) | np.uint32(instance << 16)).astype(np.uint32)


def test_label_prior_round_trips_as_one_hot_in_both_layouts(tmp_path):
    train = np.array([1, 9, 9, 15, 6, 0], np.int64)
    a = tmp_path / "a" / "sequences" / "07" / "predictions"
    b = tmp_path / "b" / "07"
    for folder in (a, b):
        folder.mkdir(parents=True)
        _labels(train, instance=3).tofile(folder / "000004.label")
    for root in (tmp_path / "a", tmp_path / "b"):
        path = find_prior(root, "07", "000004")
        probs = read_prior(path, 6, "scan.bin", LM)
        assert probs.shape == (6, LM.num_classes) and probs.dtype == np.float32
        assert np.array_equal(probs.sum(1), np.ones(6)) and np.array_equal(probs.argmax(1), train)
        assert np.array_equal(prior_classes(probs), train)  # unlabelled (0) stays 0


def test_npy_probabilities_are_taken_as_they_are(tmp_path):
    rng = np.random.default_rng(0)
    probs = rng.dirichlet(np.ones(LM.num_classes), size=50).astype(np.float32)
    (tmp_path / "00").mkdir()
    np.save(tmp_path / "00" / "000000.npy", probs)
    got = read_prior(find_prior(tmp_path, "00", "000000"), 50, "s.bin", LM)
    assert np.array_equal(got, probs)
    assert np.array_equal(prior_classes(got), probs[:, 1:].argmax(1) + 1)


def test_a_count_mismatch_names_the_prior_and_the_scan(tmp_path):
    _labels(np.ones(10, np.int64)).tofile(tmp_path / "x.label")
    with pytest.raises(PriorFormatError, match=r"x\.label: has 10 points but its scan /d/000001\.bin has 12"):
        read_prior(tmp_path / "x.label", 12, "/d/000001.bin", LM)
    np.save(tmp_path / "y.npy", np.zeros((11, LM.num_classes), np.float32))
    with pytest.raises(PriorFormatError, match=r"y\.npy: has 11 points but its scan s\.bin has 12"):
        read_prior(tmp_path / "y.npy", 12, "s.bin", LM)


def test_unknown_ids_bad_width_and_missing_files_are_refused_by_name(tmp_path):
    np.array([10, 999, 40], np.uint32).tofile(tmp_path / "u.label")
    with pytest.raises(
        PriorFormatError, match=r"u\.label: raw class ids \[999\] are not in the semantic-kitti"
    ):
        read_prior(tmp_path / "u.label", 3, "s.bin", LM)
    np.save(tmp_path / "w.npy", np.zeros((3, 7), np.float32))
    with pytest.raises(PriorFormatError, match=r"w\.npy: has 7 classes per point; .* 20 train ids"):
        read_prior(tmp_path / "w.npy", 3, "s.bin", LM)
    np.save(tmp_path / "i.npy", np.zeros((3, LM.num_classes), np.int32))
    with pytest.raises(PriorFormatError, match=r"i\.npy: expected float"):
        read_prior(tmp_path / "i.npy", 3, "s.bin", LM)
    (tmp_path / "t.label").write_bytes(b"abc")
    with pytest.raises(PriorFormatError, match=r"t\.label: size 3 B"):
        read_prior(tmp_path / "t.label", 3, "s.bin", LM)
    with pytest.raises(
        PriorFormatError, match=r"predictions/000009\.label: no semantic prior for frame 000009"
    ):
        find_prior(tmp_path, "05", "000009")
