"""``--labels``: corrections over the target logs' scans, or a review folder of its own scans; the
held-back part only when it makes three frames; ambiguous frames refused."""

import shutil
from types import SimpleNamespace

import pytest

from dsnet_core.adapt import AdaptConfig
from dsnet_core.errors import ConfigError
from dsnet_core.io.semantickitti import SemanticKittiReader
from tasks.adapt_sources import corrected_frames
from tests.helpers.tiny_log import write_tiny_log


def labels_only(log, out, frames):
    (out / "sequences/00/labels").mkdir(parents=True)
    for f in frames:
        shutil.copyfile(
            log / f"sequences/00/labels/{f:06d}.label", out / f"sequences/00/labels/{f:06d}.label"
        )
    return out


def options(labels, holdout=0.3):
    return SimpleNamespace(labels=labels, holdout=holdout)


def test_corrections_read_over_the_target_scans_and_held_back_from_three(tmp_path):
    log = write_tiny_log(tmp_path / "log", frames=10, n=300)
    target = SemanticKittiReader(log)
    cfg = AdaptConfig(label_weight=3.0, seed=2)
    ten = labels_only(log, tmp_path / "ten", range(10))
    train, held, keys = corrected_frames(options(ten), [target], cfg)
    assert len(train) == 7 and len(held) == 3 and keys == {("00", f"{i:06d}") for i in range(10)}
    assert all(it.weight == 3.0 and it.kind == "corrected" for it in train + held)
    assert train[0].reader.labels(train[0].refs[-1]).shape == (len(target.scan(train[0].refs[-1])),)
    five = labels_only(log, tmp_path / "five", [0, 2, 4, 6, 8])
    train, held, _ = corrected_frames(options(five), [target], cfg)  # 0.3 · 5 → 2 < 3: none held back
    assert len(train) == 5 and held == []


def test_a_review_folder_of_another_log_and_refusals(tmp_path):
    target = SemanticKittiReader(write_tiny_log(tmp_path / "target", frames=2, n=300, sequence="05"))
    review = write_tiny_log(tmp_path / "review", frames=3, n=300, sequence="00")
    train, held, keys = corrected_frames(options(review, 0.0), [target], AdaptConfig())
    assert len(train) == 3 and held == [] and ("00", "000002") in keys
    assert str(train[0].reader.root) == str(review.resolve())
    other = SemanticKittiReader(write_tiny_log(tmp_path / "other", frames=2, n=300, sequence="05"))
    fixes = tmp_path / "fixes"
    (fixes / "sequences/05/labels").mkdir(parents=True)
    shutil.copyfile(
        tmp_path / "target/sequences/05/labels/000001.label", fixes / "sequences/05/labels/000001.label"
    )
    with pytest.raises(ConfigError, match=r"matches frames of .* give one target log per --labels folder"):
        corrected_frames(options(fixes), [target, other], AdaptConfig())
    with pytest.raises(ConfigError, match="no corrected frames"):
        corrected_frames(options(tmp_path / "empty"), [target], AdaptConfig())
    assert corrected_frames(options(None), [target], AdaptConfig()) == ([], [], set())
