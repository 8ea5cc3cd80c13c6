"""The equivariant network trains through the ordinary stages: the backbone learns through the
pooled logits of all n copies, the offset stage trains the instance and anchor heads with the
eq. 9 loss; n is recorded in the card and a resumed run must ask for the same n."""

import math
from dataclasses import replace

import pytest
import torch

from dsnet_core.errors import CheckpointMismatchError
from dsnet_core.io.semantickitti import SemanticKittiReader
from dsnet_core.labels import load_label_map
from dsnet_core.model.checkpoint import load_checkpoint, read_card
from dsnet_core.model.cylinder import CylinderGrid
from dsnet_core.model.presets import PRESETS
from dsnet_core.train.loop import TrainConfig, Trainer
from tests.helpers.tiny_log import write_tiny_log

LM = load_label_map("semantic-kitti")
GRID = CylinderGrid(size=(24, 32, 8), min_bound=(0.0, -math.pi, -2.0), max_bound=(24.0, math.pi, 1.5))
EQ4 = replace(PRESETS["tiny"], grid=GRID, equivariant=4)


@pytest.fixture(autouse=True, scope="module")
def one_thread():
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


def test_equivariant_training_stages(tmp_path):
    log = write_tiny_log(tmp_path / "log", frames=2)
    reader = SemanticKittiReader(log)

    def run(config, resume=False, **kw):
        cfg = TrainConfig(augment=False, lr=0.01, **kw)
        return Trainer(
            tmp_path / "ckpt", config, reader, ["00"], reader, ["00"], LM, cfg, resume=resume
        ).run()

    torch.manual_seed(0)
    run(EQ4, stage="semantic", epochs={"semantic": 1})
    first, _ = load_checkpoint(tmp_path / "ckpt")
    card = run(EQ4, resume=True, stage="offset", epochs={"offset": 1})
    second, _ = load_checkpoint(tmp_path / "ckpt")
    assert read_card(tmp_path / "ckpt").architecture["equivariant"] == 4
    assert card.epochs == {"semantic": 1, "offset": 1} and math.isfinite(card.metrics[-1]["val_offset_l1"])
    a, b = first.state_dict(), second.state_dict()
    changed = {k.split(".")[0] for k in a if not torch.equal(a[k], b[k])}
    assert changed == {"ins_head", "anchor_head"}
    with pytest.raises(CheckpointMismatchError, match="equivariant"):
        run(replace(EQ4, equivariant=2), resume=True, stage="offset", epochs={"offset": 2})
