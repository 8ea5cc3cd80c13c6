"""The one trainer skeleton every method's trainer fills in (DS-Net, MOST, D-PLS, adaptation).

What it owns:

- the checkpoint folder: a kill at any moment leaves the previous epoch or the new one
  (:mod:`dsnet_core.train.commit`: every epoch's files staged, then committed together), a new
  run refuses a folder that holds a checkpoint unless it resumes;
- the schedule: stages in order, each from its first pending epoch, with the learning rate of
  ``epoch_lr(stage, epoch, total)`` (a function of the epoch index only, so a resumed run trains
  exactly as an uninterrupted one), the optimiser state of the epoch it resumes restored;
- the metrics: one record per epoch in the card and ``metrics.json`` / ``metrics.csv``;
- the card's training record (``train_config``, the code version);
- hooks for early stopping and data-parallel training (``dist``).

A trainer subclass sets :attr:`TrainerSkeleton.stage_names` and :attr:`metric_columns` and
implements ``epochs_of``, ``optimizer``, ``train_epoch``, ``validate`` and ``write_checkpoint``;
a stage that is not a plain optimiser loop (DS-Net's shifting MLPs) overrides :meth:`run_stage`.
"""

from __future__ import annotations

import csv
import json
import logging
import time
from abc import ABC, abstractmethod
from collections.abc import Callable
from pathlib import Path
from typing import Any, ClassVar

import torch

from dsnet_core.errors import ConfigError
from dsnet_core.model.checkpoint import CARD, ModelCard
from dsnet_core.train import commit
from dsnet_core.train.distributed import Distributed
from dsnet_core.train.state import load_train_state, save_train_state

log = logging.getLogger(__name__)

StepCallback = Callable[[str, int, int, int, float], None]
"""``(stage, epoch, step, steps, loss)`` after every training step."""


def prepare_out(out: Path, resume: bool, dist: Distributed = Distributed()) -> bool:
    """Bring ``out`` to its last committed epoch (on the main process); returns whether it holds
    a checkpoint.

    Raises:
        ConfigError: it holds one and ``resume`` is False.
    """
    recovered = dist.from_main(lambda: commit.recover(out))
    if recovered:
        log.info("%s: finished or discarded the epoch a kill interrupted", out)
    exists = (out / CARD).is_file()
    if exists and not resume:
        raise ConfigError(f"{out} already holds a checkpoint: pass --resume, or choose another --out")
    return exists


def write_metrics(out: Path, metrics: list[dict], columns: tuple[str, ...]) -> None:
    """``metrics.json`` (the full records) and ``metrics.csv`` (``columns``) in folder ``out``."""
    (out / "metrics.json").write_text(json.dumps(metrics, indent=2))
    with open(out / "metrics.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(columns), extrasaction="ignore")
        w.writeheader()
        w.writerows(metrics)


class TrainerSkeleton(ABC):
    """The shared loop. Subclasses set ``out``, ``card``, ``model`` and ``device`` in their
    constructor, and ``dist`` (a :class:`~dsnet_core.train.distributed.Distributed`) when they
    train data-parallel (one process by default: every collective a no-op).

    Attributes:
        stage_names: the stages in the order they train.
        metric_columns: the scalar columns of ``metrics.csv``.
    """

    stage_names: ClassVar[tuple[str, ...]]
    metric_columns: ClassVar[tuple[str, ...]]

    out: Path
    card: ModelCard
    model: torch.nn.Module
    device: torch.device
    dist: Distributed = Distributed()

    # -- what a trainer fills in -----------------------------------------------------------------
    @abstractmethod
    def epochs_of(self, stage: str) -> int:
        """Epochs ``stage`` trains in all (0: the stage does not run)."""

    @abstractmethod
    def epoch_lr(self, stage: str, epoch: int, total: int) -> float:
        """The learning rate of 0-based ``epoch`` of ``total``."""

    @abstractmethod
    def optimizer(self, stage: str) -> torch.optim.Optimizer:
        """The optimiser of ``stage`` (its parameters set trainable, the rest frozen)."""

    @abstractmethod
    def train_epoch(
        self, stage: str, epoch: int, opt: torch.optim.Optimizer, on_step: StepCallback | None, net
    ) -> float:
        """Train one epoch; ``net`` is the model as trained (its DDP wrapper when data-parallel).
        Returns the mean step loss."""

    @abstractmethod
    def validate(self, stage: str) -> dict[str, Any]:
        """The validation record of the current weights (``val_*`` keys)."""

    @abstractmethod
    def write_checkpoint(self, staging: Path, stage: str, extra: dict[str, Any]) -> None:
        """Write the weights, the card and any other file of the epoch into ``staging``."""

    # -- hooks with defaults ----------------------------------------------------------------------
    def valid_epochs(self, stage: str) -> int:
        """Completed epochs of ``stage`` that still hold (a trainer whose later stages depend on the
        earlier ones' weights discounts those trained on older weights)."""
        return self.card.epochs.get(stage, 0)

    def stopped_early(self, stage: str, done: int) -> bool:
        stop = self.card.training_data.get("early_stop", {}).get(stage)
        return bool(stop) and stop.get("stopped_after") == done

    def before_stage(self, stage: str, done: int) -> None:
        """Called before a stage's first pending epoch (e.g. record the incoming weights' score)."""
        return None

    def after_epoch(self, stage: str, epoch: int, total: int) -> bool:
        """Called after each epoch is saved; True ends the stage (early stopping)."""
        return False

    def wrap(self) -> torch.nn.Module:
        """The model as trained: its DDP wrapper under torchrun, else itself."""
        return self.dist.wrap(self.model, self.device)

    # -- the loop ---------------------------------------------------------------------------------
    def schedule(self) -> list[str]:
        """The stages this run trains, in order (default: every stage)."""
        return list(self.stage_names)

    def run(self, on_step: StepCallback | None = None) -> ModelCard:
        """Train every pending epoch of every stage; returns the final card."""
        for stage in self.schedule():
            done, total = self.valid_epochs(stage), self.epochs_of(stage)
            if done >= total or self.stopped_early(stage, done):
                continue
            self.run_stage(stage, done, total, on_step)
        return self.card

    def run_stage(self, stage: str, done: int, total: int, on_step: StepCallback | None) -> None:
        """Epochs ``done`` … ``total − 1`` of an optimiser stage, each saved as it ends."""
        opt = self.optimizer(stage)
        net = self.wrap()  # after optimizer() chose the trained parameters
        if load_train_state(self.out, opt, {"stage": stage, "epochs": done}):
            log.info("restored optimiser state of %s epoch %d", stage, done)
        self.before_stage(stage, done)
        for epoch in range(done, total):
            t0 = time.perf_counter()
            lr = self.epoch_lr(stage, epoch, total)
            for group in opt.param_groups:
                group["lr"] = lr
            loss = self.train_epoch(stage, epoch, opt, on_step, net)
            record = {"stage": stage, "epoch": epoch + 1, "train_loss": loss, **self.validate(stage)}
            record["seconds"] = round(time.perf_counter() - t0, 2)
            record["lr"] = lr
            self.end_epoch(stage, epoch + 1, record, opt)
            if self.after_epoch(stage, epoch + 1, total):
                break

    def end_epoch(
        self, stage: str, epochs_done: int, record: dict, opt: torch.optim.Optimizer | None, **extra: Any
    ) -> None:
        """Record the epoch in the card and save it."""
        self.card.metrics.append(record)
        self.card.epochs[stage] = epochs_done
        self.save(stage, epochs_done, opt, **extra)
        shown = {k: v for k, v in record.items() if k.startswith("val_") and isinstance(v, float)}
        log.info(
            "%s epoch %d: loss %.4f %s", stage, epochs_done, record.get("train_loss", float("nan")), shown
        )

    def save(self, stage: str, epochs_done: int, opt: torch.optim.Optimizer | None, **extra: Any) -> None:
        """Write the epoch's files together: the optimiser state, the checkpoint and the metrics.
        The main process writes; the others wait until the files are in place."""
        if self.dist.is_main:
            staging = commit.begin(self.out)
            if opt is not None:
                save_train_state(staging, opt, {"stage": stage, "epochs": epochs_done})
            self.write_checkpoint(staging, stage, extra)
            write_metrics(staging, self.card.metrics, self.metric_columns)
            commit.commit(self.out)
        self.dist.barrier()
