"""Training D-PLS's prior-conditioned instance network (``dsnet train dpls``).

The network (:mod:`dsnet_core.model.dpls`) starts from a trained DS-Net checkpoint (its offsets
exactly, the prior's input columns at zero) and trains everything but a semantic head it does not
have: point MLP, U-Net and instance head. The loss is the paper's Huber loss between predicted and
ground-truth centres, masked to thing points (the prior masks nothing inside the network). The
prior each step sees is ground truth corrupted realistically (:mod:`dsnet_core.train.prior_noise`):
segment-level class confusions drawn from the starting model's confusion matrix on the validation
data, scaled per sample between clean and harsher, plus blob errors at class boundaries.

Checkpoints every epoch (weights, card, optimiser state, committed together: the shared
:class:`~dsnet_core.train.skeleton.TrainerSkeleton`, which also runs the steps: batches, mixed
precision, data-parallel under torchrun); ``resume`` continues after the last completed epoch with
the same per-epoch seeds.
"""

from __future__ import annotations

import logging
import shutil
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch

from dsnet_core.errors import ConfigError
from dsnet_core.io.reader import LogReader
from dsnet_core.labels import LabelMap, class_map_of
from dsnet_core.model.bundle import SHIFT_WEIGHTS
from dsnet_core.model.checkpoint import ModelCard, code_version, load_checkpoint, save_checkpoint
from dsnet_core.model.dpls import dpls_config, init_from_semantic, is_dpls, one_hot
from dsnet_core.model.losses import instance_centres
from dsnet_core.model.network import DSNet
from dsnet_core.train import distributed
from dsnet_core.train.data import augment, class_counts, data_fingerprint, load_sample, volume_refs
from dsnet_core.train.prior_noise import PriorNoise, corrupt_prior, normalise_confusion
from dsnet_core.train.skeleton import EpochPlan, StepConfig, TrainerSkeleton, check_step_settings, prepare_out

log = logging.getLogger(__name__)
STAGE = "dpls"
METRIC_COLUMNS = ("epoch", "lr", "train_loss", "val_offset_l1_clean", "val_offset_l1_corrupted", "seconds")


@dataclass
class DplsTrainConfig:
    """D-PLS's schedule.

    Attributes:
        epochs: passes over the training volumes.
        lr: Adam learning rate, cosine per epoch down to ``min_lr_ratio · lr``.
        scans: k, scans per 4D volume (the prior is aggregated with the points).
        seed: seeds shuffling, augmentation and corruption per epoch.
        augment: yaw/flip/scale/translation augmentation.
        device: torch device.
        huber_delta: the Huber loss's transition, metres.
        strength: (min, max) per-sample scale of the confusion matrix's errors.
        blobs_per_100k: boundary blobs per 100 000 points.
        schedule, batch_size, amp, grad_clip: the step loop's
            (:class:`~dsnet_core.train.skeleton.StepConfig`).
    """

    epochs: int = 6
    lr: float = 1e-3
    scans: int = 1
    seed: int = 0
    augment: bool = True
    device: str = "cpu"
    min_lr_ratio: float = 0.05
    huber_delta: float = 1.0
    strength: tuple[float, float] = (0.0, 1.5)
    blobs_per_100k: float = 20.0
    schedule: str = "cosine"
    batch_size: int = 1
    amp: str = "off"
    grad_clip: float = 0.0

    def __post_init__(self) -> None:
        check_step_settings(self)


@dataclass(frozen=True)
class DplsSample:
    """One training volume as a step takes it: points ``(N, C)`` float32 (augmented), the
    corrupted prior ``(N,)`` int64, instance ids ``(N,)`` and the thing mask ``(N,)`` bool."""

    points: np.ndarray
    prior: np.ndarray
    inst: np.ndarray
    thing: np.ndarray


def centre_loss(offsets, xyz, centres, valid, delta: float) -> torch.Tensor:
    """Huber loss between predicted centres ``xyz + offsets`` and ``centres``, summed over x, y, z and
    averaged over the ``valid`` (thing) points; 0 without any."""
    if not bool(valid.any()):
        return offsets.sum() * 0.0
    pred = xyz[valid] + offsets[valid]
    return torch.nn.functional.huber_loss(pred, centres[valid], delta=delta, reduction="none").sum(1).mean()


class DplsTrainer(TrainerSkeleton):
    """Trains a D-PLS instance network.

    Args:
        out: checkpoint folder (written every epoch).
        reader, sequences: training data; val_reader, val_sequences: validation data.
        label_map: the class map (the starting checkpoint's must equal it).
        config: the schedule.
        init_from: a trained DS-Net checkpoint to start from (required for a new ``out``).
        resume: continue the checkpoint in ``out``.
        confusion: ``(C, C)`` confusion matrix of the corruption; None measures ``init_from``'s on the
            validation volumes.
    """

    def __init__(
        self,
        out: str | Path,
        reader: LogReader,
        sequences: list[str],
        val_reader: LogReader,
        val_sequences: list[str],
        label_map: LabelMap,
        config: DplsTrainConfig,
        init_from: str | Path | None = None,
        resume: bool = False,
        confusion: np.ndarray | None = None,
    ) -> None:
        self.out, self.cfg, self.label_map = Path(out), config, label_map
        self.step = StepConfig.of(config)
        self.dist, self.device = distributed.setup(config.device)
        self.reader, self.val_reader = reader, val_reader
        self.train_vols = volume_refs(reader, sequences, config.scans)
        self.val_vols = volume_refs(val_reader, val_sequences, config.scans)
        if not self.train_vols:
            raise ConfigError(f"no labelled frames in {reader.root} sequences {sequences}")
        if prepare_out(self.out, resume, self.dist):
            self.model, self.card = load_checkpoint(self.out, self.device, expect_label_map=label_map)
            if not is_dpls(self.model.config):
                raise ConfigError(
                    f"{self.out} holds a DS-Net checkpoint, not a D-PLS one: choose another --out"
                )
            confusion = np.asarray(self.card.training_data["prior_noise"]["confusion"])
        else:
            if init_from is None:
                raise ConfigError("dsnet train dpls starts from a trained DS-Net: pass --init-from")
            self.model, confusion = self._start(init_from, label_map, confusion)
        self.noise = PriorNoise(confusion, strength=config.strength, blobs_per_100k=config.blobs_per_100k)
        self.card.training_data["train_config"] = {**asdict(config), "world_size": self.dist.world_size}
        self.card.code_version = code_version()

    def _start(self, init_from, label_map: LabelMap, confusion) -> tuple[DSNet, np.ndarray]:
        source, parent = load_checkpoint(init_from, self.device, expect_label_map=label_map)
        torch.manual_seed(self.cfg.seed)
        model = DSNet(dpls_config(source.config)).to(self.device)
        fresh = init_from_semantic(model, source)
        measured = confusion is None
        if measured:  # once, on rank 0
            confusion = self.dist.from_main(
                lambda: measure_confusion(source, self.val_reader, self.val_vols, label_map, self.device)
            )
        # the corruption draws from the matrix as the card records it, so a resumed run (which reads
        # it back from the card) corrupts exactly as the uninterrupted one
        confusion = np.round(np.asarray(confusion, np.float64), 6)
        if self.dist.is_main:
            self.out.mkdir(parents=True, exist_ok=True)
            if (Path(init_from) / SHIFT_WEIGHTS).is_file():  # its features start as the parent's
                shutil.copyfile(Path(init_from) / SHIFT_WEIGHTS, self.out / SHIFT_WEIGHTS)
        self.card = ModelCard(
            architecture=model.config.to_dict(),
            class_map=class_map_of(label_map),
            training_data={
                "method": "dpls",
                "root": str(self.reader.root),
                "volumes": len(self.train_vols),
                "scans": self.cfg.scans,
                "fingerprint": data_fingerprint(self.reader, self.train_vols),
                "class_points": class_counts(self.reader, self.train_vols, label_map).tolist(),
                "val_root": str(self.val_reader.root),
                "init_from": {
                    "path": str(Path(init_from).resolve()),
                    "weights_sha256": parent.weights_sha256,
                    "fresh_parameters": fresh,
                },
                "prior_noise": {
                    "confusion": confusion.tolist(),
                    "confusion_source": "init_from on the validation volumes" if measured else "given",
                },
            },
            epochs={},
            metrics=[],
        )
        return model, confusion

    # -- the skeleton's hooks ---------------------------------------------------------------
    stage_names = (STAGE,)
    metric_columns = METRIC_COLUMNS

    def epochs_of(self, stage: str) -> int:
        return self.cfg.epochs

    def optimizer(self, stage: str) -> torch.optim.Optimizer:
        return torch.optim.Adam(self.model.parameters(), lr=self.cfg.lr)

    def before_stage(self, stage: str, done: int) -> None:
        if done == 0 and not self.card.metrics:  # the starting weights' scores, as epoch 0
            self.card.metrics.append({"stage": STAGE, "epoch": 0, **self.validate()})

    def write_checkpoint(self, staging: Path, stage: str, extra: dict) -> None:
        if (self.out / SHIFT_WEIGHTS).is_file():
            shutil.copyfile(self.out / SHIFT_WEIGHTS, staging / SHIFT_WEIGHTS)
        save_checkpoint(staging, self.model, self.card)

    def epoch_plan(self, stage: str, epoch: int) -> EpochPlan:
        return self.shuffled_plan([self.cfg.seed, 7, epoch], len(self.train_vols), self._sample)

    def _sample(self, i: int, rng: np.random.Generator) -> DplsSample:
        """Volume ``i``, augmented, with its ground truth corrupted into the prior."""
        s = load_sample(self.reader, self.train_vols[i], self.label_map)
        pts = augment(s.points, rng) if self.cfg.augment else s.points
        prior = corrupt_prior(pts[:, :3], s.sem, s.inst, self.noise, rng)
        return DplsSample(np.ascontiguousarray(pts), prior, s.inst, s.thing)

    def loss(
        self, stage: str, batch: list[DplsSample], net: torch.nn.Module, rng: np.random.Generator
    ) -> torch.Tensor:
        """The Huber centre loss of the batch's thing points (instances kept apart per sample)."""
        clouds = [torch.from_numpy(s.points).to(self.device) for s in batch]
        c = self.model.config.prior_channels
        out = net(clouds, priors=[one_hot(s.prior, c).to(self.device) for s in batch])
        xyz = torch.cat([cloud[:, :3] for cloud in clouds])
        keys = np.concatenate([s.inst + (b << 40) * (s.inst > 0) for b, s in enumerate(batch)])
        valid = torch.from_numpy(np.concatenate([s.thing for s in batch])).to(self.device)
        centres = instance_centres(xyz, torch.from_numpy(keys).to(self.device), valid)
        return centre_loss(out.offsets, xyz, centres, valid, self.cfg.huber_delta)

    def validate(self, stage: str | None = None) -> dict:
        """Mean L1 centre error (metres) over thing points of the validation volumes, with the clean
        ground-truth prior and with a corrupted one (seeded, the same every epoch)."""
        self.model.eval()
        rng = np.random.default_rng([self.cfg.seed, 99])
        sums = {"clean": 0.0, "corrupted": 0.0}
        n = 0
        c = self.model.config.prior_channels
        with torch.inference_mode():
            for refs in self.val_vols:
                s = load_sample(self.val_reader, refs, self.label_map)
                if not s.thing.any():
                    continue
                pts = torch.from_numpy(s.points).to(self.device)
                valid = torch.from_numpy(s.thing).to(self.device)
                centres = instance_centres(pts[:, :3], torch.from_numpy(s.inst).to(self.device), valid)
                target = (centres - pts[:, :3])[valid]
                noisy = corrupt_prior(s.points[:, :3], s.sem, s.inst, self.noise, rng)
                for key, prior in (("clean", s.sem), ("corrupted", noisy)):
                    out = self.model([pts], priors=[one_hot(prior, c).to(self.device)])
                    sums[key] += float((out.offsets[valid] - target).abs().sum())
                n += int(valid.sum())
        return {f"val_offset_l1_{k}": v / n if n else float("nan") for k, v in sums.items()}


def measure_confusion(model: DSNet, reader: LogReader, volumes, label_map: LabelMap, device) -> np.ndarray:
    """Row-normalised ``(C, C)`` confusion of a semantic model's predictions on ``volumes``."""
    c = label_map.num_classes
    counts = np.zeros((c, c), np.int64)
    model.eval()
    with torch.inference_mode():
        for refs in volumes:
            s = load_sample(reader, refs, label_map)
            out = model([torch.from_numpy(s.points).to(device)], instance=False)
            pred = (out.logits[:, 1:].argmax(1) + 1).cpu().numpy()
            counts += np.bincount(s.sem * c + pred, minlength=c * c).reshape(c, c)
    return normalise_confusion(counts)
