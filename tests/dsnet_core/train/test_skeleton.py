"""The trainer skeleton's step loop on a toy trainer (a linear model, SGD): batches cover the epoch,
the learning rate follows the one cosine schedule, gradients are clipped to the norm asked for,
bf16 autocast leaves float32 weights, and a resumed run equals an uninterrupted one."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from dsnet_core.errors import ConfigError
from dsnet_core.model.checkpoint import ModelCard
from dsnet_core.train.skeleton import (
    EpochPlan,
    StepConfig,
    TrainerSkeleton,
    config_from,
    cosine_lr,
    prepare_out,
)

N, DIM = 7, 4


class ToyTrainer(TrainerSkeleton):
    """y = w·x on ``N`` fixed samples; one stage ``fit``; SGD."""

    stage_names = ("fit",)
    metric_columns = ("stage", "epoch", "lr", "train_loss", "seconds")

    def __init__(self, out, step: StepConfig, epochs: int = 3, resume: bool = False) -> None:
        self.out, self.step, self.epochs, self.device = out, step, epochs, torch.device("cpu")
        gen = torch.Generator().manual_seed(0)
        self.x = torch.randn(N, DIM, generator=gen) * 10
        self.y = self.x @ torch.arange(1.0, DIM + 1)
        self.model = torch.nn.Linear(DIM, 1, bias=False)
        torch.nn.init.zeros_(self.model.weight)
        self.card = ModelCard(architecture={}, class_map={}, training_data={}, epochs={}, metrics=[])
        if prepare_out(out, resume):
            self.model.load_state_dict(torch.load(out / "toy.pt"))
            self.card.epochs = dict(torch.load(out / "epochs.pt"))
            self.card.metrics = [{"stage": "fit"}] * sum(self.card.epochs.values())
        self.loaded: list[list[int]] = []
        self.after: int = 0
        self.dtypes: list[torch.dtype] = []

    def epochs_of(self, stage: str) -> int:
        return self.epochs

    def optimizer(self, stage: str) -> torch.optim.Optimizer:
        return torch.optim.SGD(self.model.parameters(), lr=self.step.lr)

    def epoch_plan(self, stage: str, epoch: int) -> EpochPlan:
        self.loaded.append([])
        return self.shuffled_plan([5, epoch], N, self._load)

    def _load(self, i: int, rng: np.random.Generator) -> int:
        self.loaded[-1].append(i)
        return i

    def loss(self, stage, batch, net, rng) -> torch.Tensor:
        idx = torch.tensor(batch)
        pred = net(self.x[idx]).squeeze(1)
        self.dtypes.append(pred.dtype)
        return ((pred.float() - self.y[idx]) ** 2).mean()

    def after_step(self, stage: str) -> None:
        self.after += 1

    def validate(self, stage: str) -> dict:
        return {}

    def write_checkpoint(self, staging, stage, extra) -> None:
        torch.save(self.model.state_dict(), staging / "toy.pt")
        torch.save(dict(self.card.epochs), staging / "epochs.pt")
        (staging / "card.json").write_text("{}")


def test_batches_cover_every_sample_once_per_epoch_and_the_last_batch_is_short(tmp_path):
    t = ToyTrainer(tmp_path, StepConfig(lr=1e-4, batch_size=3))
    steps: list[tuple[int, int, int]] = []
    t.run(on_step=lambda stage, epoch, step, total, loss: steps.append((epoch, step, total)))
    assert [s for s in steps if s[0] == 1] == [(1, 1, 3), (1, 2, 3), (1, 3, 3)]  # ceil(7 / 3)
    assert len(steps) == 9 and t.after == 9
    assert all(sorted(order) == list(range(N)) for order in t.loaded)
    assert t.loaded[0] != t.loaded[1]  # each epoch its own seeded order
    assert [m["lr"] for m in t.card.metrics] == [cosine_lr(1e-4, e, 3, 0.02) for e in range(3)]


def test_the_cosine_schedule_and_the_constant_one():
    assert cosine_lr(1.0, 0, 5, 0.1) == 1.0
    assert cosine_lr(1.0, 4, 5, 0.1) == pytest.approx(0.1)
    assert cosine_lr(1.0, 2, 5, 0.1) == pytest.approx(0.1 + 0.45 * (1 + math.cos(math.pi / 2)))
    assert cosine_lr(2.0, 0, 1, 0.1) == 2.0  # a stage of one epoch trains at lr
    assert StepConfig(lr=0.5, schedule="constant").epoch_lr(3, 5) == 0.5


def test_a_step_moves_the_weights_by_at_most_the_clipped_gradient(tmp_path):
    """SGD at lr 1: one step moves the weights by the clipped gradient, whose norm is the clip."""
    t = ToyTrainer(tmp_path / "a", StepConfig(lr=1.0, schedule="constant", batch_size=N, grad_clip=0.5), 1)
    t.run()
    assert float(t.model.weight.detach().norm()) == pytest.approx(0.5, rel=1e-5)  # the raw one is far larger
    free = ToyTrainer(tmp_path / "b", StepConfig(lr=1.0, schedule="constant", batch_size=N), 1)
    free.run()
    assert float(free.model.weight.detach().norm()) > 100


def test_bf16_autocast_computes_in_bf16_and_keeps_float32_weights(tmp_path):
    t = ToyTrainer(tmp_path, StepConfig(lr=1e-4, amp="bf16"), 1)
    t.run()
    assert set(t.dtypes) == {torch.bfloat16}
    assert t.model.weight.dtype == torch.float32 and bool(t.model.weight.abs().sum() > 0)


def test_a_resumed_run_trains_as_an_uninterrupted_one(tmp_path):
    step = StepConfig(lr=1e-4, batch_size=2)
    straight = ToyTrainer(tmp_path / "a", step, 3)
    straight.run()
    ToyTrainer(tmp_path / "b", step, 1).run()
    resumed = ToyTrainer(tmp_path / "b", step, 3, resume=True)
    resumed.run()
    assert resumed.card.epochs == {"fit": 3}
    assert torch.equal(resumed.model.weight, straight.model.weight)


def test_step_settings_are_refused_in_one_line():
    with pytest.raises(ConfigError, match="unknown --amp 'fp8'"):
        StepConfig(amp="fp8")
    with pytest.raises(ConfigError, match="unknown learning-rate schedule 'step'"):
        StepConfig(schedule="step")
    with pytest.raises(ConfigError, match="grad_clip must be >= 0"):
        StepConfig(grad_clip=-1.0)
    with pytest.raises(ConfigError, match="batch_size must be >= 1"):
        StepConfig(batch_size=0)


def test_a_config_takes_the_options_that_name_its_fields():
    options = {"lr": 0.5, "amp": "bf16", "out": "/x", "threads": 4}  # out, threads: not the config's
    assert config_from(StepConfig, options, batch_size=4) == StepConfig(lr=0.5, amp="bf16", batch_size=4)
    assert StepConfig.of(StepConfig(grad_clip=2.0)) == StepConfig(grad_clip=2.0)
