"""``dsnet train dsnet DIR --init-from CKPT`` with the fine-tuning options, in process."""

import torch
from typer.testing import CliRunner

from dsnet_core.model.checkpoint import load_checkpoint, read_card
from flows.cli import app
from tests.dsnet_core.train.test_loop import trainer
from tests.helpers.tiny_log import write_tiny_log


def test_fine_tune_options(tmp_path):
    before = torch.get_num_threads()
    log = write_tiny_log(tmp_path / "log", frames=5)
    trainer(log, tmp_path / "parent", stage="semantic", epochs={"semantic": 1}).run()
    args = [
        "train",
        "dsnet",
        str(log),
        "--out",
        str(tmp_path / "ft"),
        "--init-from",
        str(tmp_path / "parent"),
    ]
    args += ["--epochs", "semantic=1,offset=0,shift=0", "--freeze-backbone", "--holdout", "0.2"]
    args += ["--patience", "1", "--no-augment", "--lr", "0.01"]
    res = CliRunner().invoke(app, args)
    torch.set_num_threads(before)
    assert res.exit_code == 0, res.output
    assert "validating on the training sequences" not in res.output
    card = read_card(tmp_path / "ft")
    data = card.training_data
    assert len(data["frames"]) == 4 and len(data["val_frames"]) == 1
    assert data["train_config"]["freeze_backbone"] is True and "semantic" in data["early_stop"]
    parent, _ = load_checkpoint(tmp_path / "parent")
    child, _ = load_checkpoint(tmp_path / "ft")
    p, c = parent.state_dict(), child.state_dict()
    assert all(torch.equal(p[k], c[k]) for k in p if k.startswith(("backbone.", "point_encoder.")))
