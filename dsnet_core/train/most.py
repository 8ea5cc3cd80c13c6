"""MOST's two-stage training (paper, implementation details): ``detect`` trains the network on
detection, segmentation and velocity (eq. 1, 2, 4); ``member`` trains PointSegMLP (eq. 3) with
everything else frozen. Checkpoints every epoch; a killed run resumes from the last completed
epoch with the optimiser state of that epoch, every epoch's files committed together. The shared
:class:`~dsnet_core.train.skeleton.TrainerSkeleton` runs the steps (batches, mixed precision,
data-parallel under torchrun); this module supplies the samples and the two losses.
"""

from __future__ import annotations

import logging
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch

from dsnet_core.errors import ConfigError
from dsnet_core.io.reader import LogReader
from dsnet_core.labels import LabelMap
from dsnet_core.model.checkpoint import ModelCard, class_map_of, code_version, load_checkpoint
from dsnet_core.model.losses import class_weights
from dsnet_core.most.checkpoint import load_most_checkpoint, save_most_checkpoint
from dsnet_core.most.config import DEFAULT_SCANS, MostConfig
from dsnet_core.most.data import MostSample, SequenceTargets
from dsnet_core.most.losses import membership_loss
from dsnet_core.most.network import MostNet, load_backbone_from
from dsnet_core.train import distributed
from dsnet_core.train.data import class_counts, data_fingerprint, volume_refs
from dsnet_core.train.metrics import ConfusionMeter
from dsnet_core.train.most_steps import (
    Augmentation,
    decode_sample,
    detect_loss,
    detection_stats,
    jittered_detections,
    member_pairs,
)
from dsnet_core.train.skeleton import EpochPlan, StepConfig, TrainerSkeleton, check_step_settings, prepare_out

log = logging.getLogger(__name__)
MOST_STAGES = ("detect", "member")
METRIC_COLUMNS = (
    "stage",
    "epoch",
    "lr",
    "train_loss",
    "val_miou",
    "val_det_precision",
    "val_det_recall",
    "val_centre_err",
    "val_extent_l1",
    "val_velocity_l1",
    "val_member_acc",
    "val_member_bce",
    "seconds",
)


@dataclass
class MostTrainConfig:
    """MOST's schedule.

    Attributes:
        stage: ``detect``, ``member`` or ``all``.
        epochs: per stage.
        lr: Adam learning rate (both stages; cosine per stage down to ``min_lr_ratio · lr``).
        scans: k, the current scan plus k − 1 past ones.
        seed, augment, device: as :class:`dsnet_core.train.loop.TrainConfig`.
        schedule, min_lr_ratio, batch_size, amp, grad_clip: the step loop's
            (:class:`~dsnet_core.train.skeleton.StepConfig`); a ``member`` batch's loss is the mean
            of its samples' PointSegMLP losses.
        min_points: instances with fewer points in a scan are no detection target there.
        jitter: standard deviation (m) of the ground-truth centres PointSegMLP trains on.
        pairs_per_object: at most this many random RoI pairs per centre and step.
    """

    stage: str = "all"
    epochs: dict[str, int] = field(default_factory=lambda: {"detect": 8, "member": 3})
    lr: float = 1e-3
    scans: int = DEFAULT_SCANS
    seed: int = 0
    augment: bool = True
    device: str = "cpu"
    min_lr_ratio: float = 0.02
    min_points: int = 5
    jitter: float = 0.3
    pairs_per_object: int = 256
    schedule: str = "cosine"
    batch_size: int = 1
    amp: str = "off"
    grad_clip: float = 0.0

    def __post_init__(self) -> None:
        check_step_settings(self)

    def stages(self) -> list[str]:
        if self.stage == "all":
            return list(MOST_STAGES)
        if self.stage not in MOST_STAGES:
            raise ConfigError(f"unknown MOST training stage '{self.stage}' (choose detect, member or all)")
        return [self.stage]


class MostTrainer(TrainerSkeleton):
    """Trains a :class:`MostNet`.

    Args:
        out: checkpoint folder. config: architecture (a resumed run keeps the checkpoint's).
        reader, sequences, val_reader, val_sequences: data. label_map: class map.
        train_config: schedule. resume: continue from ``out``.
        backbone_from: a DS-Net checkpoint whose point encoder, backbone and semantic head start
            the network (the shared backbone); ignored when resuming.
    """

    def __init__(
        self,
        out: str | Path,
        config: MostConfig,
        reader: LogReader,
        sequences: list[str],
        val_reader: LogReader,
        val_sequences: list[str],
        label_map: LabelMap,
        train_config: MostTrainConfig,
        resume: bool = False,
        backbone_from: str | Path | None = None,
    ) -> None:
        self.out, self.cfg, self.label_map = Path(out), train_config, label_map
        self.step = StepConfig.of(train_config)
        self.dist, self.device = distributed.setup(train_config.device)
        self.reader, self.val_reader = reader, val_reader
        self.train_items = _items(reader, sequences)
        self.val_items = _items(val_reader, val_sequences)
        if not self.train_items:
            raise ConfigError(f"no labelled frames in {reader.root} sequences {sequences}")
        self.train_targets = SequenceTargets(reader, sequences, label_map, train_config.min_points)
        self.val_targets = SequenceTargets(val_reader, val_sequences, label_map, train_config.min_points)
        if prepare_out(self.out, resume, self.dist):
            self.model, self.card = load_most_checkpoint(self.out, self.device, expect_label_map=label_map)
            log.info("resuming from %s (epochs done: %s)", self.out, self.card.epochs)
        else:
            torch.manual_seed(train_config.seed)
            self.model = MostNet(config).to(self.device)
            extra = {}
            if backbone_from is not None:
                dsnet, parent = load_checkpoint(backbone_from, "cpu", expect_label_map=label_map)
                load_backbone_from(self.model, dsnet.state_dict())
                extra = {
                    "backbone_from": {
                        "path": str(Path(backbone_from).resolve()),
                        "weights_sha256": parent.weights_sha256,
                        "epochs": parent.epochs,
                    }
                }
            vols = volume_refs(reader, sequences, 1)
            self.card = ModelCard(
                architecture=config.to_dict(),
                class_map=class_map_of(label_map),
                training_data={
                    "root": str(reader.root),
                    "sequences": list(sequences),
                    "frames": len(self.train_items),
                    "scans": train_config.scans,
                    "fingerprint": data_fingerprint(reader, vols),
                    "class_points": class_counts(reader, vols, label_map).tolist(),
                    "val_root": str(val_reader.root),
                    "val_sequences": list(val_sequences),
                    **extra,
                },
            )
        self.card.training_data["train_config"] = {**asdict(train_config), "world_size": self.dist.world_size}
        self.card.code_version = code_version()
        self.weights = class_weights(np.asarray(self.card.training_data["class_points"])).to(self.device)

    # -- the skeleton's hooks ---------------------------------------------------------------
    stage_names = MOST_STAGES
    metric_columns = METRIC_COLUMNS

    def schedule(self) -> list[str]:
        return self.cfg.stages()

    def epochs_of(self, stage: str) -> int:
        return self.cfg.epochs.get(stage, 0)

    def write_checkpoint(self, staging: Path, stage: str, extra: dict) -> None:
        save_most_checkpoint(staging, self.model, self.card)

    def valid_epochs(self, stage: str) -> int:
        """``member`` epochs recorded before the last ``detect`` epoch were trained on older features."""
        recorded = self.card.epochs.get(stage, 0)
        if stage == "detect":
            return recorded
        last = max((i for i, m in enumerate(self.card.metrics) if m["stage"] == "detect"), default=-1)
        valid = sum(1 for m in self.card.metrics[last + 1 :] if m["stage"] == stage)
        if valid < recorded:
            log.info("PointSegMLP was trained on an older backbone: retraining it")
            self.card.epochs[stage] = valid
        return min(valid, recorded)

    def optimizer(self, stage: str) -> torch.optim.Optimizer:
        for name, p in self.model.named_parameters():
            p.requires_grad_(name.startswith("pointseg.") == (stage == "member"))
        return torch.optim.Adam([p for p in self.model.parameters() if p.requires_grad], lr=self.cfg.lr)

    def wrap(self, stage: str | None = None) -> torch.nn.Module:
        """``member`` trains PointSegMLP alone: it is the module wrapped (and called) there."""
        module = self.model.pointseg if stage == "member" else self.model
        return self.dist.wrap(module, self.device)

    def train_modes(self, stage: str) -> None:
        self.model.train()
        if stage == "member":  # frozen first stage: batch-norm statistics stay fixed
            for name, mod in self.model.named_children():
                if name != "pointseg":
                    mod.eval()

    def epoch_plan(self, stage: str, epoch: int) -> EpochPlan:
        key = [self.cfg.seed, MOST_STAGES.index(stage), epoch]
        return self.shuffled_plan(key, len(self.train_items), self._train_sample)

    def _train_sample(self, i: int, rng: np.random.Generator) -> MostSample:
        sample = self._sample(self.train_targets, self.train_items[i])
        return Augmentation.draw(rng).apply(sample) if self.cfg.augment else sample

    def loss(
        self, stage: str, batch: list[MostSample], net: torch.nn.Module, rng: np.random.Generator
    ) -> torch.Tensor:
        """``detect``: eq. 1 + 2 + 4 of the batch through ``net`` (the model); ``member``: eq. 3 of
        each sample through ``net`` (PointSegMLP), averaged."""
        if stage == "detect":
            return detect_loss(net, batch, self.weights, self.device)[0]
        losses = [self._member_loss(sample, rng, net) for sample in batch]
        return losses[0] if len(losses) == 1 else torch.stack(losses).mean()

    def _member_loss(
        self, sample: MostSample, rng: np.random.Generator, pointseg: torch.nn.Module
    ) -> torch.Tensor:
        with torch.no_grad():
            out = self.model([torch.from_numpy(sample.points).to(self.device)])
        det = jittered_detections(sample.targets, rng, self.cfg.jitter)
        feats, target = member_pairs(self.model, out, sample, det, rng, self.cfg.pairs_per_object)
        if feats.shape[0] < 2:  # batch norm needs two rows
            if self.dist.active:  # every rank's DDP step needs a gradient of every parameter
                return pointseg(feats.new_zeros((2, feats.shape[1]))).sum() * 0.0
            return self.model.pointseg.mlp[0].weight.sum() * 0.0
        return membership_loss(pointseg(feats), target)

    def _sample(self, targets: SequenceTargets, item: tuple[str, int]) -> MostSample:
        seq, pos = item
        return targets.sample(targets.reader.frames(seq), pos, self.cfg.scans)

    # -- validation ------------------------------------------------------------------------
    def validate(self, stage: str) -> dict:
        """mIoU of the current scans, detection precision/recall at 1 m, centre/extent/velocity
        errors of matched detections; after ``member``, PointSegMLP's pair accuracy and BCE."""
        self.model.eval()
        meter = ConfusionMeter(self.model.config.backbone.num_classes)
        sums: dict[str, float] = {}
        mem_ok = mem_n = 0
        mem_loss = 0.0
        rng = np.random.default_rng(12345)
        with torch.inference_mode():
            for item in self.val_items:
                s = self._sample(self.val_targets, item)
                out = self.model([torch.from_numpy(s.points).to(self.device)])
                meter.add((out.logits[: s.n_current, 1:].argmax(1) + 1).cpu().numpy(), s.sem)
                for k, v in detection_stats(decode_sample(self.model, out), s.targets).items():
                    sums[k] = sums.get(k, 0.0) + v
                if stage == "member":
                    det = jittered_detections(s.targets, rng, self.cfg.jitter)
                    feats, target = member_pairs(self.model, out, s, det, rng, 0)
                    if feats.shape[0]:
                        logits = self.model.pointseg(feats)
                        mem_ok += int(((logits > 0) == target).sum())
                        mem_n += int(target.numel())
                        mem_loss += float(membership_loss(logits, target)) * int(target.numel())
        tp = sums.get("tp", 0.0)
        rec = {
            "val_miou": meter.miou(),
            "val_det_precision": tp / max(sums.get("det", 0.0), 1.0),
            "val_det_recall": tp / max(sums.get("obj", 0.0), 1.0),
            "val_centre_err": sums.get("centre_err", 0.0) / max(tp, 1.0),
            "val_extent_l1": sums.get("extent_err", 0.0) / max(tp, 1.0),
            "val_velocity_l1": sums.get("vel_err", 0.0) / max(sums.get("vel_n", 0.0), 1.0),
        }
        if stage == "member":
            rec["val_member_acc"] = mem_ok / max(mem_n, 1)
            rec["val_member_bce"] = mem_loss / max(mem_n, 1)
        return rec


def _items(reader: LogReader, sequences: list[str]) -> list[tuple[str, int]]:
    return [(seq, f.index) for seq in sequences for f in reader.frames(seq) if f.label_path is not None]
