"""``DplsTrainer``: records the measured confusion it corrupts priors with, checkpoints an epoch,
refuses to overwrite, and resumes after the last completed epoch."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from dsnet_core.errors import ConfigError
from dsnet_core.io.semantickitti import SemanticKittiReader
from dsnet_core.labels import load_label_map
from dsnet_core.model.checkpoint import load_checkpoint
from dsnet_core.model.dpls import is_dpls
from dsnet_core.train.dpls import DplsTrainConfig, DplsTrainer
from tests.model_helpers import make_checkpoint

LM = load_label_map("semantic-kitti")


def _trainer(log, out, parent, epochs, resume=False):
    reader = SemanticKittiReader(log)
    cfg = DplsTrainConfig(epochs=epochs, lr=1e-3, seed=3)
    return DplsTrainer(out, reader, ["00"], reader, ["01"], LM, cfg, init_from=parent, resume=resume)


def test_train_an_epoch_then_resume(synth_log, tmp_path):
    torch.set_num_threads(1)
    parent = make_checkpoint(tmp_path / "parent")
    trainer = _trainer(synth_log, tmp_path / "out", parent, 1)
    confusion = np.asarray(trainer.card.training_data["prior_noise"]["confusion"])
    assert confusion.shape == (20, 20) and np.allclose(confusion.sum(1), 1, atol=1e-5)
    card = trainer.run()
    assert card.epochs == {"dpls": 1} and [m["epoch"] for m in card.metrics] == [0, 1]
    model, _ = load_checkpoint(tmp_path / "out")
    assert is_dpls(model.config) and (tmp_path / "out" / "shift.safetensors").is_file()
    with pytest.raises(ConfigError, match="already holds a checkpoint"):
        _trainer(synth_log, tmp_path / "out", parent, 1)
    again = _trainer(synth_log, tmp_path / "out", parent, 2, resume=True)
    assert again.card.epochs == {"dpls": 1}
    assert again.run().epochs == {"dpls": 2}
    assert np.array_equal(np.asarray(again.card.training_data["prior_noise"]["confusion"]), confusion)


def test_bf16_batches_of_two(synth_log, tmp_path):
    """The skeleton's step loop gives D-PLS mixed precision and batches (instances kept apart per
    sample): half the steps, a finite loss close to full precision's, float32 weights."""
    torch.set_num_threads(1)
    parent = make_checkpoint(tmp_path / "parent")
    reader = SemanticKittiReader(synth_log)

    def run(out, **kw):
        cfg = DplsTrainConfig(epochs=1, lr=1e-3, seed=3, **kw)
        steps: list[int] = []
        t = DplsTrainer(out, reader, ["00"], reader, ["01"], LM, cfg, init_from=parent)
        card = t.run(on_step=lambda stage, epoch, step, total, loss: steps.append(total))
        return card, set(steps)

    plain, plain_steps = run(tmp_path / "fp32")
    mixed, mixed_steps = run(tmp_path / "bf16", amp="bf16", batch_size=2)
    assert (plain_steps, mixed_steps) == ({6}, {3})  # six volumes of sequence 00
    assert mixed.training_data["train_config"]["amp"] == "bf16"
    a, b = plain.metrics[-1]["train_loss"], mixed.metrics[-1]["train_loss"]
    assert np.isfinite(b) and abs(a - b) < 0.5 * a, (a, b)
    model, _ = load_checkpoint(tmp_path / "bf16")
    assert all(p.dtype == torch.float32 for p in model.parameters())
