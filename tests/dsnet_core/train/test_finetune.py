"""Fine-tuning options: frozen backbone, a held-back validation part, early stopping."""

import pytest
import torch

from dsnet_core.errors import ConfigError
from dsnet_core.io.semantickitti import SemanticKittiReader
from dsnet_core.model.bundle import load_shift_weights
from dsnet_core.model.checkpoint import load_checkpoint
from dsnet_core.train.data import volume_refs
from dsnet_core.train.finetune import holdout_split, volume_name
from dsnet_core.train.loop import TrainConfig, Trainer
from tests.dsnet_core.train.test_loop import LM, TINY, one_thread, trainer  # noqa: F401
from tests.helpers.tiny_log import write_tiny_log


@pytest.fixture(scope="module")
def log(tmp_path_factory):
    return write_tiny_log(tmp_path_factory.mktemp("log"), frames=5)


def test_holdout_split_is_seeded_and_never_empty(log):
    vols = volume_refs(SemanticKittiReader(log), ["00"])
    train, val = holdout_split(vols, 0.2, seed=3)
    assert len(val) == 1 and len(train) == 4
    assert holdout_split(vols, 0.2, seed=3)[1] == val
    assert {volume_name(v) for v in train} | {volume_name(v) for v in val} == {volume_name(v) for v in vols}
    assert len(holdout_split(vols, 0.9, seed=0)[0]) == 1  # at least one volume left to train on
    with pytest.raises(ConfigError, match="holdout"):
        TrainConfig(holdout=1.0)


def test_frozen_backbone_trains_only_the_semantic_head(log, tmp_path):
    trainer(log, tmp_path / "parent", stage="semantic", epochs={"semantic": 1}).run()
    parent, _ = load_checkpoint(tmp_path / "parent")
    reader = SemanticKittiReader(log)
    cfg = TrainConfig(
        augment=False, lr=0.01, stage="semantic", epochs={"semantic": 1}, freeze_backbone=True, holdout=0.2
    )
    card = Trainer(
        tmp_path / "ft", TINY, reader, ["00"], reader, ["00"], LM, cfg, init_from=tmp_path / "parent"
    ).run()
    child, _ = load_checkpoint(tmp_path / "ft")
    before, after = parent.state_dict(), child.state_dict()
    assert all(torch.equal(before[k], after[k]) for k in before if not k.startswith("sem_head."))
    assert not torch.equal(before["sem_head.conv.weight"], after["sem_head.conv.weight"])
    data = card.training_data
    assert len(data["frames"]) == 4 and len(data["val_frames"]) == 1
    assert not set(data["frames"]) & set(data["val_frames"])
    assert data["init_from"]["weights_sha256"] == load_checkpoint(tmp_path / "parent")[1].weights_sha256
    assert "shift_weights" not in data["init_from"]  # the parent had none


def test_fine_tune_inherits_the_parents_shifting_weights(log, tmp_path):
    trainer(log, tmp_path / "p", stage="all", epochs={"semantic": 1, "offset": 1, "shift": 1}).run()
    reader = SemanticKittiReader(log)
    cfg = TrainConfig(augment=False, lr=0.01, stage="semantic", epochs={"semantic": 1})
    card = Trainer(
        tmp_path / "c", TINY, reader, ["00"], reader, ["00"], LM, cfg, init_from=tmp_path / "p"
    ).run()
    assert card.training_data["init_from"]["shift_weights"] == "inherited"
    parent, child = load_shift_weights(tmp_path / "p"), load_shift_weights(tmp_path / "c")
    assert all(torch.equal(parent[k], child[k]) for k in parent)


class ScriptedValidation(Trainer):
    """A real trainer whose validation mIoU follows a script, so that when early stopping happens
    does not hang on floating-point details of a diverging run (they differ between CPUs and
    thread counts); training, checkpoints and resume are the real ones."""

    SCRIPT = (0.10, 0.30, 0.50, 0.40, 0.45, 0.60, 0.70)  # the incoming weights, then epochs 1..6

    def validate(self, stage: str | None = None) -> dict:
        self.calls = getattr(self, "calls", 0) + 1
        return {**super().validate(stage), "val_miou": self.SCRIPT[self.calls - 1]}


def scripted(root, out, resume=False, **kw):
    reader = SemanticKittiReader(root)
    cfg = TrainConfig(**{"augment": False, "lr": 0.01, **kw})
    return ScriptedValidation(out, TINY, reader, ["00"], reader, ["00"], LM, cfg, resume=resume)


def test_early_stop_keeps_the_best_epoch_and_resume_respects_it(log, tmp_path):
    kw = dict(stage="semantic", epochs={"semantic": 6}, patience=1, holdout=0.4, schedule="constant")
    first = scripted(log, tmp_path / "two", **{**kw, "epochs": {"semantic": 2}})  # stops at the best
    first.run()
    best_weights = {k: v.clone() for k, v in first.model.state_dict().items()}
    card = scripted(log, tmp_path, **kw).run()
    stop = card.training_data["early_stop"]["semantic"]
    assert [m["val_miou"] for m in card.metrics] == [0.30, 0.50, 0.40]
    assert stop == {"best_epoch": 2, "stopped_after": 3, "score": "val_miou", "value": 0.50}
    assert not (tmp_path / "best_semantic.safetensors").exists()
    model, _ = load_checkpoint(tmp_path)  # the best epoch's weights, not the last trained ones
    assert all(torch.equal(best_weights[k], v) for k, v in model.state_dict().items())
    again = scripted(log, tmp_path, resume=True, **kw).run()  # the stopped stage is not trained again
    assert len(again.metrics) == len(card.metrics)


def test_a_stage_that_never_beats_its_start_keeps_the_incoming_weights(log, tmp_path):
    trainer(log, tmp_path / "p", stage="all", epochs={"semantic": 1, "offset": 2, "shift": 0}).run()
    parent, _ = load_checkpoint(tmp_path / "p")
    reader = SemanticKittiReader(log)
    # a learning rate this high ruins the offsets in one epoch
    cfg = TrainConfig(augment=False, lr=50.0, stage="offset", epochs={"offset": 2}, patience=1, holdout=0.4)
    card = Trainer(
        tmp_path / "c", TINY, reader, ["00"], reader, ["00"], LM, cfg, init_from=tmp_path / "p"
    ).run()
    stop = card.training_data["early_stop"]["offset"]
    assert stop["best_epoch"] == 0 and stop["value"] == card.training_data["stage_start"]["offset"]
    child, _ = load_checkpoint(tmp_path / "c")
    assert all(torch.equal(v, child.state_dict()[k]) for k, v in parent.state_dict().items())
