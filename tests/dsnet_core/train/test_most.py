"""MOST's two training stages on a tiny log: losses fall, checkpoints resume exactly, the first
stage stays frozen in the second, the card is MOST's own."""

import math
from dataclasses import replace

import numpy as np
import pytest
import torch

from dsnet_core.checkpoints import checkpoint_method
from dsnet_core.errors import CheckpointError, ConfigError
from dsnet_core.io.semantickitti import SemanticKittiReader
from dsnet_core.labels import load_label_map
from dsnet_core.model.checkpoint import ModelCard, class_map_of, save_checkpoint
from dsnet_core.model.cylinder import CylinderGrid
from dsnet_core.model.network import DSNet
from dsnet_core.model.presets import PRESETS
from dsnet_core.most.checkpoint import load_most_checkpoint
from dsnet_core.most.config import BevGrid, MostConfig
from dsnet_core.train.most import MostTrainConfig, MostTrainer
from tests.helpers.tiny_log import write_tiny_log

LM = load_label_map("semantic-kitti")
GRID = CylinderGrid(size=(24, 32, 8), min_bound=(0.0, -math.pi, -2.0), max_bound=(24.0, math.pi, 1.5))
BB = replace(PRESETS["tiny"], width=2, point_mlp=(8, 8), compress=4, grid=GRID)
CFG = MostConfig(backbone=BB, bev=BevGrid(half_extent=24.0, cell=1.0), bev_channels=8, mem_widths=(16, 16, 8))


@pytest.fixture(autouse=True, scope="module")
def one_thread():
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture(scope="module")
def log(tmp_path_factory):
    return write_tiny_log(tmp_path_factory.mktemp("log"), frames=3)


def trainer(root, out, resume=False, backbone_from=None, **kw):
    reader = SemanticKittiReader(root)
    cfg = MostTrainConfig(**{"augment": False, "lr": 0.01, "scans": 2, "pairs_per_object": 64, **kw})
    return MostTrainer(
        out, CFG, reader, ["00"], reader, ["00"], LM, cfg, resume=resume, backbone_from=backbone_from
    )


def test_resumed_training_equals_uninterrupted(log, tmp_path):
    straight = trainer(log, tmp_path / "a", epochs={"detect": 2, "member": 2}).run()
    trainer(log, tmp_path / "b", stage="detect", epochs={"detect": 1}).run()
    trainer(log, tmp_path / "b", resume=True, epochs={"detect": 2, "member": 1}).run()
    resumed = trainer(log, tmp_path / "b", resume=True, epochs={"detect": 2, "member": 2}).run()
    assert resumed.epochs == straight.epochs == {"detect": 2, "member": 2}
    assert [m["train_loss"] for m in resumed.metrics] == [m["train_loss"] for m in straight.metrics]
    a, card = load_most_checkpoint(tmp_path / "a")
    b, _ = load_most_checkpoint(tmp_path / "b")
    for (k, x), (_, y) in zip(a.state_dict().items(), b.state_dict().items(), strict=True):
        assert torch.equal(x, y), k
    assert card.format == "most-checkpoint/1" and card.architecture["method"] == "most"
    assert card.training_data["scans"] == 2 and checkpoint_method(tmp_path / "a") == "most"
    rows = (tmp_path / "b" / "metrics.csv").read_text().splitlines()
    assert rows[0].startswith("stage,epoch,lr,train_loss,val_miou,val_det_precision") and len(rows) == 5
    member = [m for m in resumed.metrics if m["stage"] == "member"]
    assert all(0.0 <= m["val_member_acc"] <= 1.0 and np.isfinite(m["val_member_bce"]) for m in member)


def test_member_stage_freezes_the_first_stage(log, tmp_path):
    trainer(log, tmp_path, stage="detect", epochs={"detect": 1}).run()
    before, _ = load_most_checkpoint(tmp_path)
    trainer(log, tmp_path, resume=True, stage="member", epochs={"member": 1}).run()
    after, _ = load_most_checkpoint(tmp_path)
    sa, sb = before.state_dict(), after.state_dict()
    changed = {k for k in sa if not torch.equal(sa[k], sb[k])}
    assert changed and all(k.startswith("pointseg.") for k in changed)
    # training the first stage again invalidates PointSegMLP's epochs
    card2 = trainer(log, tmp_path, resume=True, epochs={"detect": 2, "member": 1}).run()
    stages = [m["stage"] for m in card2.metrics]
    assert stages == ["detect", "member", "detect", "member"] and card2.epochs == {"detect": 2, "member": 1}


def test_detect_loss_falls(log, tmp_path):
    card = trainer(log, tmp_path, stage="detect", epochs={"detect": 4}).run()
    losses = [m["train_loss"] for m in card.metrics]
    assert losses[-1] < 0.7 * losses[0]


def test_backbone_from_a_dsnet_checkpoint_and_errors(log, tmp_path):
    torch.manual_seed(0)
    ds = DSNet(BB)
    save_checkpoint(
        tmp_path / "ds", ds, ModelCard(architecture={}, class_map=class_map_of(LM), code_version="test")
    )
    t = trainer(log, tmp_path / "m", backbone_from=tmp_path / "ds", epochs={"detect": 0, "member": 0})
    assert t.card.training_data["backbone_from"]["weights_sha256"]
    torch.testing.assert_close(t.model.backbone.state_dict(), ds.backbone.state_dict())
    assert checkpoint_method(tmp_path / "ds") == "dsnet"
    with pytest.raises(CheckpointError, match="not a MOST checkpoint"):
        load_most_checkpoint(tmp_path / "ds")
    trainer(log, tmp_path / "m", stage="detect", epochs={"detect": 1}).run()
    with pytest.raises(ConfigError, match="already holds a checkpoint: pass --resume"):
        trainer(log, tmp_path / "m", stage="detect", epochs={"detect": 1})
    with pytest.raises(ConfigError, match="unknown MOST training stage 'shift'"):
        trainer(log, tmp_path / "x", stage="shift").run()


def test_bf16_batches_of_two_train_both_stages_in_float32_weights(log, tmp_path):
    """The skeleton's step loop gives MOST mixed precision and batches: the same epochs in half
    the steps, losses close to full precision, float32 weights, the card records the choice."""
    kw = dict(epochs={"detect": 1, "member": 1})
    plain = trainer(log, tmp_path / "fp32", **kw).run()
    steps: list[tuple[str, int]] = []
    mixed = trainer(log, tmp_path / "bf16", amp="bf16", batch_size=2, **kw).run(
        on_step=lambda stage, epoch, step, total, loss: steps.append((stage, total))
    )
    assert set(steps) == {("detect", 2), ("member", 2)}  # 3 labelled frames in batches of two
    assert (
        mixed.training_data["train_config"] | {"amp": "bf16", "batch_size": 2, "world_size": 1}
        == (mixed.training_data["train_config"])
    )
    for a, b in zip(plain.metrics, mixed.metrics, strict=True):
        assert np.isfinite(b["train_loss"]) and b["train_loss"] < 3 * a["train_loss"], (a, b)
    model, _ = load_most_checkpoint(tmp_path / "bf16")
    assert all(p.dtype == torch.float32 for p in model.parameters())
    with pytest.raises(ConfigError, match="--amp"):
        MostTrainConfig(amp="fp8")
