import itertools
import math
from dataclasses import replace

import pytest
import torch

from dsnet_core.errors import ConfigError
from dsnet_core.io.semantickitti import SemanticKittiReader
from dsnet_core.labels import load_label_map
from dsnet_core.model.bundle import load_shift_weights
from dsnet_core.model.checkpoint import load_checkpoint
from dsnet_core.model.cylinder import CylinderGrid
from dsnet_core.model.presets import PRESETS
from dsnet_core.train.loop import TrainConfig, Trainer
from dsnet_core.train.skeleton import StepConfig, cosine_lr
from tests.helpers.tiny_log import write_tiny_log

LM = load_label_map("semantic-kitti")
# a coarse grid so that the tiny log's few thousand points fill their voxels
GRID = CylinderGrid(size=(24, 32, 8), min_bound=(0.0, -math.pi, -2.0), max_bound=(24.0, math.pi, 1.5))
TINY = replace(PRESETS["tiny"], grid=GRID)


def trainer(root, out, resume=False, **kw):
    reader = SemanticKittiReader(root)
    cfg = TrainConfig(**{"augment": False, "lr": 0.01, **kw})
    return Trainer(out, TINY, reader, ["00"], reader, ["00"], LM, cfg, resume=resume)


@pytest.fixture(autouse=True, scope="module")
def one_thread():
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture(scope="module")
def log(tmp_path_factory):
    return write_tiny_log(tmp_path_factory.mktemp("log"), frames=2)


def test_resumed_training_equals_uninterrupted(log, tmp_path):
    straight = trainer(log, tmp_path / "a", stage="semantic", epochs={"semantic": 2}).run()
    trainer(log, tmp_path / "b", stage="semantic", epochs={"semantic": 1}).run()
    resumed = trainer(log, tmp_path / "b", resume=True, stage="semantic", epochs={"semantic": 2}).run()
    assert resumed.epochs == straight.epochs == {"semantic": 2}
    assert [m["train_loss"] for m in resumed.metrics] == [m["train_loss"] for m in straight.metrics]
    a, _ = load_checkpoint(tmp_path / "a")
    b, _ = load_checkpoint(tmp_path / "b")
    for (k, x), (_, y) in zip(a.state_dict().items(), b.state_dict().items(), strict=True):
        assert torch.equal(x, y), k
    rows = (tmp_path / "b" / "metrics.csv").read_text().splitlines()
    assert rows[0] == "stage,epoch,lr,train_loss,val_miou,val_offset_l1,val_shift_l1,seconds"
    assert len(rows) == 3


def test_existing_checkpoint_needs_resume(log, tmp_path):
    trainer(log, tmp_path, stage="semantic", epochs={"semantic": 1}).run()
    with pytest.raises(ConfigError, match="already holds a checkpoint: pass --resume"):
        trainer(log, tmp_path, stage="semantic", epochs={"semantic": 1})


def test_all_stages_write_shift_weights(log, tmp_path):
    card = trainer(log, tmp_path, stage="all", epochs={"semantic": 1, "offset": 1, "shift": 1}).run()
    assert card.epochs == {"semantic": 1, "offset": 1, "shift": 1}
    assert [m["stage"] for m in card.metrics] == ["semantic", "offset", "shift"]
    shift = card.metrics[-1]
    assert shift["train_loss"] > 0 and shift["val_shift_l1"] > 0
    weights = load_shift_weights(tmp_path)
    assert (
        weights is not None and "mlps.0.0.weight" in weights and weights["mlps.0.0.weight"].shape == (32, 32)
    )
    # the network itself is frozen during the shift stage: its weights equal those after 'offset'
    rows = (tmp_path / "metrics.csv").read_text().splitlines()
    assert rows[0].split(",")[-2] == "val_shift_l1" and len(rows) == 4


def test_a_run_resumed_at_the_shift_stage_trains_the_same_shifting_weights(log, tmp_path):
    """The shifting MLPs' initial weights come from the run's seed, not from whatever the process
    drew before: a run resumed at the shift stage (a fresh process that did not train the earlier
    stages) ends with the uninterrupted run's weights, bit for bit."""
    epochs = {"semantic": 1, "offset": 1, "shift": 1}
    trainer(log, tmp_path / "a", stage="all", epochs=epochs).run()
    trainer(log, tmp_path / "b", stage="all", epochs={**epochs, "shift": 0}).run()
    torch.manual_seed(12345)  # another process: the global generator is wherever it is
    trainer(log, tmp_path / "b", resume=True, stage="all", epochs=epochs).run()
    a, b = load_shift_weights(tmp_path / "a"), load_shift_weights(tmp_path / "b")
    assert a is not None and b is not None and a.keys() == b.keys()
    for k in a:
        assert torch.equal(a[k], b[k]), k


def test_unknown_stage(log, tmp_path):
    with pytest.raises(ConfigError, match="unknown training stage 'bogus'"):
        trainer(log, tmp_path, stage="bogus")


@pytest.mark.slow
@pytest.mark.timeout(3600)
def test_tiny_model_overfits_two_frames(log, tmp_path):
    t = trainer(log, tmp_path, stage="all", epochs={"semantic": 24, "offset": 12})
    card = t.run()
    sem = [m for m in card.metrics if m["stage"] == "semantic"]
    off = [m for m in card.metrics if m["stage"] == "offset"]
    assert sem[-1]["val_miou"] > 0.9
    assert sem[-1]["train_loss"] < 0.1 * sem[0]["train_loss"]
    # the instance head learns while the backbone stays frozen (semantics unchanged)
    assert off[-1]["val_offset_l1"] < 0.8 * sem[-1]["val_offset_l1"]
    assert off[-1]["val_miou"] == sem[-1]["val_miou"]


def test_cosine_schedule_runs_from_lr_to_the_floor():
    step = StepConfig.of(TrainConfig(lr=2e-3, min_lr_ratio=0.05))
    rates = [step.epoch_lr(e, 10) for e in range(10)]
    assert rates == [cosine_lr(2e-3, e, 10, 0.05) for e in range(10)]
    assert rates[0] == pytest.approx(2e-3)
    assert rates[-1] == pytest.approx(1e-4)
    assert all(a > b for a, b in itertools.pairwise(rates))
    assert rates[5] == pytest.approx(1e-4 + 0.5 * 1.9e-3 * (1 + math.cos(math.pi * 5 / 9)))
    assert StepConfig.of(TrainConfig(lr=1e-3, schedule="constant")).epoch_lr(7, 10) == 1e-3
    assert StepConfig.of(TrainConfig(lr=1e-3)).epoch_lr(0, 1) == 1e-3


def test_unknown_schedule_is_a_config_error():
    with pytest.raises(ConfigError, match="unknown learning-rate schedule 'step'"):
        TrainConfig(schedule="step")


def test_fine_tune_starts_a_new_card_from_another_checkpoint(log, tmp_path):
    trainer(log, tmp_path / "3d", stage="semantic", epochs={"semantic": 1}).run()
    parent, parent_card = load_checkpoint(tmp_path / "3d")
    reader = SemanticKittiReader(log)
    cfg = TrainConfig(augment=False, lr=0.01, stage="offset", epochs={"offset": 1}, scans=2)
    card = Trainer(
        tmp_path / "4d", PRESETS["paper"], reader, ["00"], reader, ["00"], LM, cfg, init_from=tmp_path / "3d"
    ).run()
    assert card.epochs == {"offset": 1}
    assert card.architecture == parent_card.architecture  # the parent's, not the preset passed in
    source = card.training_data["init_from"]
    assert source["weights_sha256"] == parent_card.weights_sha256 and source["epochs"] == {"semantic": 1}
    assert card.training_data["scans"] == 2
    # the training sensor, for `label --match` (the test log: dsnet synth's hdl64, 1.73 m up)
    from dsnet_core.model.sensor_match import SensorReference

    ref = SensorReference.from_dict(card.training_data["sensor_reference"], "card")
    assert ref.ground == pytest.approx(-1.73, abs=0.05) and 0 < ref.remission[50] < 1
    child, _ = load_checkpoint(tmp_path / "4d")
    before, after = parent.state_dict(), child.state_dict()
    assert all(torch.equal(before[k], after[k]) for k in before if not k.startswith("ins_head."))
    assert any(not torch.equal(before[k], after[k]) for k in before if k.startswith("ins_head."))


def test_more_backbone_epochs_invalidate_the_heads_trained_before(log, tmp_path):
    trainer(log, tmp_path, stage="all", epochs={"semantic": 1, "offset": 1, "shift": 1}).run()
    first_shift = load_shift_weights(tmp_path)
    # a longer semantic schedule later: the instance head and shifting were trained on old features
    card = trainer(log, tmp_path, resume=True, epochs={"semantic": 2, "offset": 1, "shift": 1}).run()
    assert [m["stage"] for m in card.metrics] == ["semantic", "offset", "shift"] * 2
    assert card.epochs == {"semantic": 2, "offset": 1, "shift": 1}
    assert not torch.equal(first_shift["mlps.0.0.weight"], load_shift_weights(tmp_path)["mlps.0.0.weight"])
    # nothing left to do: a further resume trains nothing
    again = trainer(log, tmp_path, resume=True, epochs={"semantic": 2, "offset": 1, "shift": 1}).run()
    assert len(again.metrics) == 6


def test_bf16_mixed_precision_trains_in_float32_weights_and_is_recorded(tmp_path):

    log = write_tiny_log(tmp_path / "log", frames=3)
    kw = dict(stage="all", epochs={"semantic": 1, "offset": 1, "shift": 0})
    plain = trainer(log, tmp_path / "fp32", **kw).run()
    mixed = trainer(log, tmp_path / "bf16", amp="bf16", **kw).run()
    assert mixed.training_data["train_config"]["amp"] == "bf16"
    for a, b in zip(plain.metrics, mixed.metrics, strict=True):  # the same steps, bf16 rounding only
        assert abs(a["train_loss"] - b["train_loss"]) < 0.05 * a["train_loss"], (a, b)
    model, _ = load_checkpoint(tmp_path / "bf16")
    assert all(p.dtype == torch.float32 for p in model.parameters())
    with pytest.raises(ConfigError, match="--amp"):
        TrainConfig(amp="fp8")


def _weights(folder):
    model, _ = load_checkpoint(folder)
    return {k: v.clone() for k, v in model.state_dict().items()}


def _changed(before, after, prefix):
    """Names under ``prefix`` whose float tensors differ between the two state dicts."""
    return [
        k
        for k in before
        if k.startswith(prefix) and before[k].is_floating_point() and not torch.equal(before[k], after[k])
    ]


def test_joint_stage_trains_the_backbone_and_the_instance_only_stage_does_not(log, tmp_path):
    """4D-DS-Net's volume fine-tune (``joint``) moves the point MLP, U-Net and both heads; the
    instance-head stage (``offset``) moves the instance head only, batch-norm statistics included."""
    trainer(log, tmp_path / "base", stage="semantic", epochs={"semantic": 1}).run()
    base = _weights(tmp_path / "base")
    reader = SemanticKittiReader(log)

    def fine_tune(out, epochs):
        cfg = TrainConfig(augment=False, lr=0.01, scans=2, stage="all", epochs=epochs)
        Trainer(out, TINY, reader, ["00"], reader, ["00"], LM, cfg, init_from=tmp_path / "base").run()
        return _weights(out)

    joint = fine_tune(tmp_path / "joint", {"joint": 1})
    head = fine_tune(tmp_path / "head", {"offset": 1})
    for prefix in ("point_encoder.", "backbone.", "sem_head.", "ins_head."):
        assert _changed(base, joint, prefix), prefix
    assert _changed(base, head, "ins_head.")
    for prefix in ("point_encoder.", "backbone.", "sem_head."):
        assert not _changed(base, head, prefix), prefix
    card = load_checkpoint(tmp_path / "joint")[1]
    assert card.epochs == {"joint": 1} and card.training_data["scans"] == 2
    (record,) = card.metrics
    assert record["stage"] == "joint" and record["val_offset_l1"] > 0 and 0 <= record["val_miou"] <= 1


def test_epochs_text_names_the_joint_stage():
    from tasks.methods.dsnet_train import PLAIN_STAGES, TRAIN_STAGES, DsnetTrainOptions

    def parse(text):
        return DsnetTrainOptions(out="x", epochs=text).epoch_counts(TRAIN_STAGES, PLAIN_STAGES)

    assert parse("3") == {"semantic": 3, "offset": 3, "joint": 0, "shift": 3}
    assert parse("joint=2,shift=1") == {"semantic": 0, "offset": 0, "joint": 2, "shift": 1}
    for bad, said in (("x", "expected N"), ("-1", "expected N"), ("bogus=1", "unknown stage 'bogus'")):
        with pytest.raises(ValueError, match=said):
            parse(bad)
