"""The one trainer skeleton every method's trainer fills in (DS-Net, MOST, D-PLS, adaptation).

What it owns:

- the checkpoint folder: a kill at any moment leaves the previous epoch or the new one
  (:mod:`dsnet_core.train.commit`: every epoch's files staged, then committed together), a new
  run refuses a folder that holds a checkpoint unless it resumes;
- the schedule: stages in order, each from its first pending epoch, with the learning rate of
  ``epoch_lr(stage, epoch, total)`` (:func:`cosine_lr` or constant: a function of the epoch index
  only, so a resumed run trains exactly as an uninterrupted one), the optimiser state of the epoch
  it resumes restored;
- the step loop (:meth:`TrainerSkeleton.train_epoch`): the epoch's samples in batches of
  ``batch_size`` (under torchrun each rank its shard of the epoch's order), the forward pass under
  autocast (``amp``: bf16, or fp16 with a gradient scaler), gradient clipping, the optimiser step,
  progress and the mean loss over every rank (:class:`StepConfig`);
- the metrics: one record per epoch in the card and ``metrics.json`` / ``metrics.csv``;
- the card's training record (``train_config``, the code version);
- hooks for early stopping and data-parallel training (``dist``).

A trainer subclass sets :attr:`TrainerSkeleton.stage_names`, :attr:`metric_columns` and ``step``
(its :class:`StepConfig`) and implements ``epochs_of``, ``optimizer``, ``epoch_plan`` (the epoch's
samples: usually :meth:`~TrainerSkeleton.shuffled_plan`), ``loss`` (of one batch), ``validate`` and
``write_checkpoint``; a stage that is not a plain optimiser loop (DS-Net's shifting MLPs) overrides
:meth:`run_stage`.
"""

from __future__ import annotations

import csv
import json
import logging
import math
import time
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, ClassVar, TypeVar

import numpy as np
import torch

from dsnet_core.errors import ConfigError
from dsnet_core.model.checkpoint import CARD, ModelCard
from dsnet_core.train import commit
from dsnet_core.train.distributed import Distributed, shard
from dsnet_core.train.state import load_train_state, save_train_state

log = logging.getLogger(__name__)

StepCallback = Callable[[str, int, int, int, float], None]
"""``(stage, epoch, step, steps, loss)`` after every training step. A callback with a ``start``
method is also called ``start(stage, epoch, steps)`` before an epoch's first step (a progress bar
then shows ``0/steps`` while a slow first step runs)."""


C = TypeVar("C")

AMP_DTYPES = {"off": None, "bf16": torch.bfloat16, "fp16": torch.float16}
"""``amp`` → the autocast dtype (None: full precision)."""
SCHEDULES = ("cosine", "constant")


def cosine_lr(lr: float, epoch: int, total: int, min_ratio: float) -> float:
    """The learning rate of 0-based ``epoch`` of ``total``: ``lr`` down to ``min_ratio · lr`` on a
    half cosine (``lr`` throughout a stage of one epoch)."""
    if total <= 1:
        return lr
    floor = lr * min_ratio
    return floor + 0.5 * (lr - floor) * (1.0 + math.cos(math.pi * epoch / (total - 1)))


def config_from(cls: type[C], values: Mapping[str, Any], **overrides: Any) -> C:
    """A dataclass ``cls`` from the entries of ``values`` that name its fields (e.g. a command's
    options, ``options.model_dump()``), then ``overrides``; the rest keep their defaults."""
    names = {f.name for f in fields(cls)}  # type: ignore[arg-type]
    return cls(**{**{k: v for k, v in values.items() if k in names}, **overrides})


@dataclass(frozen=True)
class StepConfig:
    """How the skeleton's step loop trains (every trainer's config has these fields or keeps the
    defaults: :meth:`of`).

    Attributes:
        lr: the optimiser's learning rate at the start of each stage.
        schedule: ``cosine`` (per epoch, down to ``min_lr_ratio · lr`` over a stage's epochs) or
            ``constant``.
        min_lr_ratio: the cosine schedule's floor as a fraction of ``lr``.
        batch_size: samples per step (per process under torchrun: a step's batch is
            ``batch_size × processes``).
        amp: mixed precision of the forward pass: ``off``, ``bf16`` (CPU and CUDA) or ``fp16``
            (CUDA, with a gradient scaler); weights and optimiser state stay float32.
        grad_clip: clip each step's gradient norm (over the trained parameters) to this; 0: off.
    """

    lr: float = 1e-3
    schedule: str = "cosine"
    min_lr_ratio: float = 0.02
    batch_size: int = 1
    amp: str = "off"
    grad_clip: float = 0.0

    def __post_init__(self) -> None:
        check_step_settings(self)

    @classmethod
    def of(cls, config: Any) -> StepConfig:
        """The step settings of a trainer's config (a dataclass): its fields of these names."""
        return config_from(cls, {f.name: getattr(config, f.name) for f in fields(config)})

    def epoch_lr(self, epoch: int, total: int) -> float:
        """The learning rate of 0-based ``epoch`` of a stage of ``total`` epochs."""
        if self.schedule == "constant":
            return self.lr
        return cosine_lr(self.lr, epoch, total, self.min_lr_ratio)


def check_step_settings(config: Any) -> None:
    """Refuse bad step settings of ``config`` (any object with the fields of :class:`StepConfig`
    it has).

    Raises:
        ConfigError: naming the setting and the choices.
    """
    amp = getattr(config, "amp", "off")
    if amp not in AMP_DTYPES:
        raise ConfigError(f"unknown --amp {amp!r}: choose one of {sorted(AMP_DTYPES)}")
    schedule = getattr(config, "schedule", "cosine")
    if schedule not in SCHEDULES:
        raise ConfigError(f"unknown learning-rate schedule '{schedule}' (cosine or constant)")
    if getattr(config, "batch_size", 1) < 1:
        raise ConfigError(f"batch_size must be >= 1, got {config.batch_size}")
    if getattr(config, "grad_clip", 0.0) < 0:
        raise ConfigError(f"grad_clip must be >= 0 (0: off), got {config.grad_clip}")


@dataclass
class EpochPlan:
    """An epoch's training samples as the step loop takes them.

    Attributes:
        steps: the steps of the epoch (this process's).
        batches: one list of samples per step, made as the loop asks for them (a lazy iterable:
            loading and augmentation interleave with the steps).
        rng: the epoch's random stream, handed to :meth:`TrainerSkeleton.loss`.
        order: the item indices this process trains, in order (empty when not index-based).
    """

    steps: int
    batches: Iterable[list[Any]]
    rng: np.random.Generator
    order: np.ndarray


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


def architecture_width(architecture: Mapping[str, Any]) -> int | None:
    """A card's network width: its ``width``, or its backbone's (MOST); None without one."""
    if isinstance(architecture.get("width"), int):
        return architecture["width"]
    for value in architecture.values():
        if isinstance(value, Mapping) and (found := architecture_width(value)) is not None:
            return found
    return None


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
    step: StepConfig = StepConfig()
    dist: Distributed = Distributed()

    # -- what a trainer fills in -----------------------------------------------------------------
    @abstractmethod
    def epochs_of(self, stage: str) -> int:
        """Epochs ``stage`` trains in all (0: the stage does not run)."""

    @abstractmethod
    def optimizer(self, stage: str) -> torch.optim.Optimizer:
        """The optimiser of ``stage`` (its parameters set trainable, the rest frozen)."""

    @abstractmethod
    def epoch_plan(self, stage: str, epoch: int) -> EpochPlan:
        """The samples of 0-based ``epoch`` of ``stage``, in batches (seeded by the epoch alone)."""

    @abstractmethod
    def loss(
        self, stage: str, batch: list[Any], net: torch.nn.Module, rng: np.random.Generator
    ) -> torch.Tensor:
        """The scalar loss of one batch; ``net`` is the model as trained (:meth:`wrap`), ``rng`` the
        epoch's stream (:attr:`EpochPlan.rng`)."""

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

    def epoch_lr(self, stage: str, epoch: int, total: int) -> float:
        """The learning rate of 0-based ``epoch`` of ``total`` (:meth:`StepConfig.epoch_lr`)."""
        return self.step.epoch_lr(epoch, total)

    def wrap(self, stage: str | None = None) -> torch.nn.Module:
        """The module ``stage`` trains, as trained: the model in its DDP wrapper under torchrun,
        else itself (built after :meth:`optimizer` chose the trained parameters)."""
        return self.dist.wrap(self.model, self.device)

    def train_modes(self, stage: str) -> None:
        """Set training mode before an epoch's steps (frozen parts may stay in eval mode)."""
        self.model.train()

    def after_step(self, stage: str) -> None:
        """Called after each optimiser step (e.g. an EMA teacher's update)."""
        return None

    def after_steps(self, stage: str) -> None:
        """Called after an epoch's last step, before validation."""
        return None

    # -- the step loop ----------------------------------------------------------------------------
    def shuffled_plan(
        self, key: Sequence[int], n: int, load: Callable[[int, np.random.Generator], Any]
    ) -> EpochPlan:
        """The usual epoch: a permutation of ``n`` items drawn from ``default_rng(key)`` (after the
        epoch's torch seed), under torchrun this rank's shard of it with its own stream
        ``default_rng([*key, rank])``, in batches of ``batch_size``; ``load(index, rng)`` makes one
        sample (loads and augments it)."""
        rng = np.random.default_rng(list(key))
        torch.manual_seed(int(rng.integers(2**31)))
        order = rng.permutation(n)
        if self.dist.active:  # this rank's shard of the epoch, and its own augmentation draws
            order = shard(order, self.dist.world_size, self.dist.rank)
            rng = np.random.default_rng([*key, self.dist.rank])
        bs = self.step.batch_size
        steps = (len(order) + bs - 1) // bs

        def batches():
            for step in range(steps):
                yield [load(int(i), rng) for i in order[step * bs : (step + 1) * bs]]

        return EpochPlan(steps, batches(), rng, order)

    def train_epoch(
        self,
        stage: str,
        epoch: int,
        opt: torch.optim.Optimizer,
        on_step: StepCallback | None = None,
        net: torch.nn.Module | None = None,
    ) -> float:
        """One epoch of ``stage``: every batch of :meth:`epoch_plan` through :meth:`loss` under
        autocast, backward (scaled for fp16), clipped, one optimiser step; ``net`` is the module as
        trained (default: :meth:`wrap`'s). Rank 0's batch-norm statistics are copied to every rank
        at the end.

        Returns:
            the mean step loss over all ranks.
        """
        net = self.wrap(stage) if net is None else net
        plan = self.epoch_plan(stage, epoch)
        self.announce(stage, epoch, plan)
        start = getattr(on_step, "start", None)
        if start is not None:
            start(stage, epoch + 1, plan.steps)
        self.train_modes(stage)
        dtype = AMP_DTYPES[self.step.amp]
        scaler = torch.amp.GradScaler(self.device.type, enabled=self.step.amp == "fp16")
        params = [p for group in opt.param_groups for p in group["params"]]
        losses: list[float] = []
        for step, batch in enumerate(plan.batches):
            with torch.autocast(self.device.type, dtype=dtype or torch.float32, enabled=dtype is not None):
                loss = self.loss(stage, batch, net, plan.rng)
            opt.zero_grad(set_to_none=True)
            scaler.scale(loss.float()).backward()
            if self.step.grad_clip > 0:
                scaler.unscale_(opt)
                torch.nn.utils.clip_grad_norm_([p for p in params if p.grad is not None], self.step.grad_clip)
            scaler.step(opt)
            scaler.update()
            self.after_step(stage)
            losses.append(float(loss.detach()))
            if on_step is not None:
                on_step(stage, epoch + 1, step + 1, plan.steps, losses[-1])
            if (step + 1) % 25 == 0:
                log.info(
                    "%s epoch %d step %d/%d: mean loss %.4f",
                    stage,
                    epoch + 1,
                    step + 1,
                    plan.steps,
                    np.mean(losses[-25:]),
                )
        self.after_steps(stage)
        self.dist.sync_buffers(self.model)  # rank 0's batch-norm statistics, saved and validated
        return self.mean_loss(losses)

    def announce(self, stage: str, epoch: int, plan: EpochPlan) -> None:
        """Log what this run trains, once, before its first step (a wide network's first step on a
        CPU can take minutes): the trainer, device, width and parameters, the epoch and its steps."""
        if getattr(self, "_announced", False) or not self.dist.is_main:
            return
        self._announced = True
        params = sum(p.numel() for p in self.model.parameters())
        width = architecture_width(self.card.architecture)
        log.info(
            "training %s on %s: %s%.2f M parameters; %s epoch %d of %d: %d steps per epoch (batch %d)",
            type(self).__name__,
            self.device,
            f"width {width}, " if width else "",
            params / 1e6,
            stage,
            epoch + 1,
            self.epochs_of(stage),
            plan.steps,
            self.step.batch_size,
        )

    def mean_loss(self, losses: list[float]) -> float:
        """Mean of every rank's step losses (the same value on every rank)."""
        return float(np.mean(np.concatenate(self.dist.all_gather(losses))))

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
        net = self.wrap(stage)  # after optimizer() chose the trained parameters
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
