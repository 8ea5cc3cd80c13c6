"""Pairing label files for ``dsnet eval``: raw ids the label map does not know are refused."""

import numpy as np
import pytest

from dsnet_core.errors import LabelFormatError
from dsnet_core.io import kitti
from dsnet_core.labels import load_label_map
from dsnet_core.metrics.pairing import iter_pairs, pair_label_files

LM = load_label_map("semantic-kitti")


def _write(root, folder: str, labels: np.ndarray) -> None:
    kitti.write_label(root / "sequences" / "08" / folder / "000000.label", labels)


@pytest.mark.parametrize("side", ["gt", "pred"])
def test_unknown_raw_ids_are_refused_naming_the_file(tmp_path, side):
    good = kitti.join_label(np.array([40, 40, 10, 10]), np.array([0, 0, 1, 1]))
    bad = good.copy()
    bad[1] = 12  # not a SemanticKITTI raw id
    _write(tmp_path / "gt", "labels", bad if side == "gt" else good)
    _write(tmp_path / "pred", "predictions", bad if side == "pred" else good)
    folder = "labels" if side == "gt" else "predictions"
    pairs = pair_label_files(tmp_path / "gt", tmp_path / "pred", ["08"], label_map=LM)
    with pytest.raises(
        LabelFormatError, match=rf"{folder}/000000\.label: raw semantic ids \[12\] are not in"
    ):
        list(iter_pairs(pairs))
    # without a label map the pair is read as is (library callers decide)
    ((_, g, p),) = iter_pairs(pair_label_files(tmp_path / "gt", tmp_path / "pred", ["08"]))
    assert g.shape == p.shape == (4,)
