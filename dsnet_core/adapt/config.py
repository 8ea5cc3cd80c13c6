"""The adaptation schedule (:class:`AdaptConfig`) and what a round of pseudo-labels hands the trainer
(:class:`RoundData`)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

from dsnet_core.adapt.data import Item
from dsnet_core.adapt.mixing import MIX_MODES
from dsnet_core.errors import ConfigError

MIN_HELDOUT = 3
"""Held-back corrected frames below which there is no held-out early stopping."""


@dataclass(frozen=True)
class AdaptConfig:
    """How the student trains.

    Attributes:
        rounds: label → select → train rounds; the EMA teacher relabels between them.
        steps: student steps per round (one mixed scan each; a target/source pair gives two steps).
        epochs: epochs per round (a checkpoint each); a round's steps are split evenly over them.
        lr: Adam learning rate; ``schedule`` ``constant`` or ``cosine`` (per round, down to
            ``min_lr_ratio · lr``; a function of the epoch index only, so a resume trains as an
            uninterrupted run: the trainer skeleton's
            :class:`~dsnet_core.train.skeleton.StepConfig`).
        ema: the teacher's EMA decay per student step.
        mix: ``both`` (laser or polar per pair), ``laser``, ``polar`` or ``none``.
        label_weight: loss weight of corrected frames' points (pseudo-labels and source weigh 1
            and ``source_weight``).
        scans: k, scans per volume.
        seed: seeds the order, augmentation, mixing and the source stream.
        augment: yaw/flip/scale/translation augmentation of each scan before mixing.
        device: torch device.
        patience: held-out early stopping (epochs without a better held-back mIoU; 0 = off); only
            with at least :data:`MIN_HELDOUT` held-back corrected frames.
        val_target: target frames whose agreement with the round's pseudo-labels is recorded.
    """

    rounds: int = 2
    steps: int = 200
    epochs: int = 2
    lr: float = 1e-3
    schedule: str = "constant"
    min_lr_ratio: float = 0.1
    ema: float = 0.99
    mix: str = "both"
    label_weight: float = 2.0
    source_weight: float = 1.0
    scans: int = 1
    seed: int = 0
    augment: bool = True
    device: str = "cpu"
    patience: int = 2
    val_target: int = 4

    def __post_init__(self) -> None:
        if min(self.rounds, self.steps, self.epochs, self.scans) < 1 or self.steps < self.epochs:
            raise ConfigError(
                f"adapt needs rounds, epochs, scans ≥ 1 and steps ≥ epochs, got rounds={self.rounds}, "
                f"steps={self.steps}, epochs={self.epochs}, scans={self.scans}"
            )
        if self.schedule not in ("constant", "cosine"):
            raise ConfigError(f"unknown learning-rate schedule {self.schedule!r} (constant or cosine)")
        if self.mix not in MIX_MODES:
            raise ConfigError(f"unknown mixing {self.mix!r}; choose one of {', '.join(MIX_MODES)}")
        if not 0.0 <= self.ema < 1.0 or self.lr <= 0 or self.label_weight <= 0 or self.source_weight < 0:
            raise ConfigError("adapt needs 0 ≤ ema < 1, lr > 0, label_weight > 0 and source_weight ≥ 0")

    def steps_in(self, epoch: int) -> int:
        """Student steps of 0-based ``epoch`` of a round (the first ``steps % epochs`` get one more)."""
        base, extra = divmod(self.steps, self.epochs)
        return base + (1 if epoch < extra else 0)

    def changed(self, recorded: dict) -> list[str]:
        """The settings that differ from a card's record (``rounds`` may grow on a resume, and the
        device may change)."""
        now = {k: v for k, v in asdict(self).items() if k not in ("rounds", "device")}
        return [f"{k}: {recorded.get(k)!r} → {v!r}" for k, v in now.items() if recorded.get(k) != v]


@dataclass
class RoundData:
    """A round's training targets.

    Attributes:
        items: the pseudo-labelled target volumes.
        record: what the card records of the round (coverage, thresholds, precision, ...).
    """

    items: list[Item]
    record: dict = field(default_factory=dict)


Labeller = Callable[[int, Path], RoundData]
"""``(round, teacher checkpoint) -> RoundData``: labels the target logs with the teacher (the
parent in round 1), selects the pseudo-labels, and returns them; the same answer when asked again
for a round it has finished (a resumed run)."""
