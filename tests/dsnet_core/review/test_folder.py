import json

import numpy as np
import pytest

from dsnet_core.errors import ConfigError
from dsnet_core.io.semantickitti import SemanticKittiReader
from dsnet_core.review.folder import ReviewFrame, write_review_folder


def test_review_folder_is_a_readable_log(tmp_path):
    rng = np.random.default_rng(0)
    frames = [
        ReviewFrame(
            "03",
            fid,
            rng.normal(size=(50, 4)).astype(np.float32),
            np.full(50, 10 | (2 << 16), np.uint32),
            {"score": s},
        )
        for fid, s in (("000007", 0.2), ("000012", 0.4))
    ]
    write_review_folder(tmp_path, frames, {"run": "r"})
    reader = SemanticKittiReader(tmp_path)
    refs = reader.frames("03")
    assert [r.frame_id for r in refs] == ["000007", "000012"]
    assert np.array_equal(reader.scan(refs[1]), frames[1].scan)
    assert np.array_equal(reader.labels(refs[0]), frames[0].label)
    manifest = json.loads((tmp_path / "review.json").read_text())
    assert manifest["source"] == {"run": "r"} and manifest["frames"][1]["score"] == 0.4
    with pytest.raises(ConfigError, match="already holds frames"):
        write_review_folder(tmp_path, frames, {})


def test_label_must_match_scan(tmp_path):
    bad = ReviewFrame("00", "000000", np.zeros((5, 4), np.float32), np.zeros(4, np.uint32))
    with pytest.raises(ConfigError, match="4 labels for 5 points"):
        write_review_folder(tmp_path, [bad], {})
