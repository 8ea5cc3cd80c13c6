"""The staged training loop (semantic → instance head → shifting MLPs), checkpointing every epoch.

An interrupted run resumes from the last completed epoch: the model card in the checkpoint says
which epochs are done; the optimiser state is restored when it belongs to that same epoch.

Launched by ``torchrun`` with several processes, the loop trains data-parallel
(:mod:`dsnet_core.train.distributed`): every rank takes its shard of each epoch's order,
``DistributedDataParallel`` averages the gradients, validation is split over the ranks and gathered,
and rank 0 alone writes the checkpoint while the others wait.
"""

from __future__ import annotations

import logging
import shutil
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch

from dsnet_core.errors import ConfigError
from dsnet_core.io.reader import LogReader
from dsnet_core.labels import LabelMap
from dsnet_core.model.bundle import SHIFT_WEIGHTS, load_shift_weights, save_shift_weights
from dsnet_core.model.checkpoint import (
    ModelCard,
    class_map_of,
    code_version,
    load_checkpoint,
    save_checkpoint,
)
from dsnet_core.model.equivariant import equivariant_offset_loss
from dsnet_core.model.losses import (
    class_weights,
    instance_centres,
    offset_loss,
    semantic_loss,
    voxel_labels,
)
from dsnet_core.model.network import DSNet, NetOutput, lift_model
from dsnet_core.model.presets import ModelConfig
from dsnet_core.train import distributed
from dsnet_core.train.data import (
    Sample,
    augment,
    data_fingerprint,
    load_sample,
    probe_statistics,
    volume_refs,
)
from dsnet_core.train.finetune import early_stop, holdout_split, stage_start, volume_name
from dsnet_core.train.metrics import ConfusionMeter
from dsnet_core.train.real import REAL_STREAM, RealData, centres_of, same_real
from dsnet_core.train.shifting import (
    clusterer_for,
    make_shift_module,
    shift_errors,
    shift_samples,
    train_shift,
)
from dsnet_core.train.skeleton import (
    EpochPlan,
    StepCallback,
    StepConfig,
    TrainerSkeleton,
    check_step_settings,
    prepare_out,
)
from dsnet_core.train.stream import StreamLog

log = logging.getLogger(__name__)
METRIC_COLUMNS = (
    "stage",
    "epoch",
    "lr",
    "train_loss",
    "val_miou",
    "val_offset_l1",
    "val_shift_l1",
    "seconds",
)
STAGES = ("semantic", "offset", "joint", "shift")
"""Stages in the order they run. ``joint`` (4D-DS-Net's volume fine-tune) trains the point MLP,
U-Net, semantic and instance heads together on the sum of both losses; a plain run leaves it at 0
epochs."""
STAGE_SEED = {"semantic": 0, "offset": 1, "shift": 2, "joint": 3}
"""Each stage's index in its random streams and stream windows (fixed: adding a stage must not
change what the existing ones draw)."""
INSTANCE_PARAMS = ("ins_head.", "anchor_head.")
"""Parameters the offset stage trains (the equivariant network's anchor scores included)."""


@dataclass
class TrainConfig:
    """Training schedule.

    Attributes:
        stage: "semantic", "offset", "joint", "shift" or "all".
        epochs: epochs per stage.
        lr: Adam learning rate.
        scans: scans per 4D volume (1 = single-scan).
        batch_size: volumes per step (per process under torchrun: the step's batch is
            ``batch_size × processes``).
        seed: the run's seed (augmentation and shuffling per epoch derive from it).
        augment: apply yaw/flip/scale/translation augmentation.
        device: "cpu" or "cuda" (under torchrun each process takes ``cuda:LOCAL_RANK``).
        schedule, min_lr_ratio, batch_size, amp, grad_clip: the step loop's
            (:class:`~dsnet_core.train.skeleton.StepConfig`; the rate is a function of the epoch
            index only, so a resumed run trains exactly as an uninterrupted one).
        freeze_backbone: fine-tuning: the semantic stage trains only the semantic head (point MLP
            and U-Net frozen, their batch-norm statistics fixed); False trains everything.
        holdout: fraction of the training volumes held back for validation (seeded choice, at
            least one when there are two or more); 0 validates on the given validation data.
        amp: mixed precision of the semantic, offset and joint stages' forward passes (the card
            records the choice, ``train_config.amp``).
        patience: early stop: end a stage after this many epochs without a better validation
            score (mIoU for the semantic stage, offset L1 for the instance head) and keep the best
            epoch's weights; 0 runs every epoch.
    """

    stage: str = "all"
    epochs: dict[str, int] = field(default_factory=lambda: {"semantic": 10, "offset": 5, "shift": 2})
    lr: float = 1e-3
    scans: int = 1
    batch_size: int = 1
    seed: int = 0
    augment: bool = True
    device: str = "cpu"
    schedule: str = "cosine"
    min_lr_ratio: float = 0.02
    freeze_backbone: bool = False
    holdout: float = 0.0
    patience: int = 0
    amp: str = "off"
    grad_clip: float = 0.0

    def __post_init__(self) -> None:
        check_step_settings(self)
        if not 0.0 <= self.holdout < 1.0:
            raise ConfigError(f"holdout must be a fraction in [0, 1), got {self.holdout}")
        if self.patience < 0:
            raise ConfigError(f"patience must be >= 0, got {self.patience}")

    def stages(self) -> list[str]:
        if self.stage == "all":
            return list(STAGES)
        if self.stage not in STAGES:
            raise ConfigError(
                f"unknown training stage '{self.stage}' (choose semantic, offset, joint, shift or all)"
            )
        return [self.stage]


class Trainer(TrainerSkeleton):
    stage_names = STAGES
    metric_columns = METRIC_COLUMNS

    """Trains a :class:`DSNet` on volumes read through a :class:`LogReader` (the shared loop,
    checkpoints and resume: :class:`~dsnet_core.train.skeleton.TrainerSkeleton`).

    Under torchrun (``WORLD_SIZE`` > 1) it joins the process group (:func:`distributed.setup`) and
    trains data-parallel; the caller ends the group (:func:`distributed.teardown`).

    Args:
        out: checkpoint folder (written every epoch).
        model_config: architecture (ignored when resuming: the checkpoint's is used and must match).
        reader, sequences: training data.
        val_reader, val_sequences: validation data.
        label_map: class map.
        config: schedule.
        resume: continue from the checkpoint in ``out``.
        init_from: fine-tune: start a new checkpoint in ``out`` from this checkpoint's weights (its
            architecture replaces ``model_config``; the new card starts with no epochs and records
            where it came from). Ignored when resuming an existing ``out``.
        lift: ``(n, pooling)``: lift the plain ``init_from`` model to C_n first
            (:func:`~dsnet_core.model.network.lift_model`).
        real: real labelled volumes mixed into a share of the semantic, offset and joint stages'
            samples (:mod:`dsnet_core.train.real`); recorded in the card, and a resumed run must
            name the same.
    """

    def __init__(
        self,
        out: str | Path,
        model_config: ModelConfig,
        reader: LogReader,
        sequences: list[str],
        val_reader: LogReader,
        val_sequences: list[str],
        label_map: LabelMap,
        config: TrainConfig,
        resume: bool = False,
        init_from: str | Path | None = None,
        lift: tuple[int, str] | None = None,
        real: RealData | None = None,
    ) -> None:
        self.out, self.cfg, self.label_map = Path(out), config, label_map
        self.real = real
        self.step = StepConfig.of(config)
        self.stages = config.stages()
        self.dist, self.device = distributed.setup(config.device)
        self.reader = reader
        val_sequences = self._volumes(sequences, val_reader, val_sequences)
        exists = prepare_out(self.out, resume, self.dist)
        if resume and exists:
            self.model, self.card = load_checkpoint(
                self.out, self.device, expect_config=model_config, expect_label_map=label_map
            )
            log.info("resuming from %s (epochs done: %s)", self.out, self.card.epochs)
            self._check_real(real)
        else:
            torch.manual_seed(config.seed)
            self.model, source = self._start(model_config, init_from, lift)
            self.card = self._new_card(sequences, val_sequences, source)
            if real is not None:
                self.card.training_data["real"] = self.dist.from_main(real.record)
        before = self.card.training_data.get("train_config", {}).get("world_size", 1)
        if self.card.epochs and before != self.dist.world_size:
            log.warning(
                "resuming a run trained with %d process(es) with %d: each step's batch changes, so the "
                "run does not continue as an uninterrupted one would",
                before,
                self.dist.world_size,
            )
        self.card.training_data["train_config"] = {**asdict(config), "world_size": self.dist.world_size}
        self.card.code_version = code_version()  # the code that trains now (a resumed card keeps the last)
        self.weights = class_weights(np.asarray(self.card.training_data["class_points"])).to(self.device)

    def _volumes(self, sequences: list[str], val_reader: LogReader, val_sequences: list[str]) -> list[str]:
        """Set the training and validation volumes (``holdout``: a seeded share of the training
        ones validates); returns the validation sequences."""
        reader, config = self.reader, self.cfg
        self.val_reader = val_reader
        if isinstance(reader, StreamLog):  # one volume per sample; epochs draw their own windows
            self.train_vols = reader.volumes(sequences)
        else:
            self.train_vols = volume_refs(reader, sequences, config.scans)
        if not self.train_vols:
            raise ConfigError(f"no labelled frames in {reader.root} sequences {sequences}")
        if config.holdout > 0:
            self.train_vols, self.val_vols = holdout_split(self.train_vols, config.holdout, config.seed)
            self.val_reader = reader
            return sorted({v[-1].sequence for v in self.val_vols})
        self.val_vols = volume_refs(val_reader, val_sequences, config.scans)
        return val_sequences

    def _check_real(self, real: RealData | None) -> None:
        """Refuse to resume with another ``--real`` than the checkpoint trained with.

        Raises:
            ConfigError: naming the checkpoint and what differs.
        """
        now = self.dist.from_main(real.record) if real is not None else None
        why = same_real(self.card.training_data.get("real"), now)
        if why:
            raise ConfigError(f"{self.out}: cannot resume with another --real: {why}")

    def _start(
        self, model_config: ModelConfig, init_from: str | Path | None, lift: tuple[int, str] | None
    ) -> tuple[DSNet, dict | None]:
        """The network of a new run: fresh, or ``init_from``'s (lifted to C_n with ``lift``; its
        shifting MLPs copied into ``out``), with the card's record of where it came from."""
        if init_from is None:
            return DSNet(model_config).to(self.device), None
        model, parent = load_checkpoint(init_from, self.device, expect_label_map=self.label_map)
        if lift is not None:  # a plain model's weights shared by the n rotated copies
            model = lift_model(model, *lift)
        source = {
            "path": str(Path(init_from).resolve()),
            "weights_sha256": parent.weights_sha256,
            "epochs": parent.epochs,
            "scans": parent.training_data.get("scans"),
        }
        log.info("fine-tuning from %s (epochs %s)", init_from, parent.epochs)
        if load_shift_weights(init_from) is not None:  # kept unless this run trains the shift stage again
            if self.dist.is_main:
                self.out.mkdir(parents=True, exist_ok=True)
                shutil.copyfile(Path(init_from) / SHIFT_WEIGHTS, self.out / SHIFT_WEIGHTS)
            source["shift_weights"] = "inherited"
        return model, source

    def _new_card(self, sequences: list[str], val_sequences: list[str], source: dict | None) -> ModelCard:
        """The card of a new run: the data it trains and validates on and where it started."""
        reader, stream = self.reader, isinstance(self.reader, StreamLog)
        (counts, reference), fingerprint = self.dist.from_main(  # every training file read once, on rank 0
            lambda: (
                probe_statistics(reader, self.train_vols, self.label_map),
                reader.fingerprint() if stream else data_fingerprint(reader, self.train_vols),
            )
        )
        return ModelCard(
            architecture=self.model.config.to_dict(),
            class_map=class_map_of(self.label_map),
            training_data={
                "root": str(reader.root),
                "sequences": list(sequences),
                "volumes": len(self.train_vols),
                "scans": self.cfg.scans,
                "fingerprint": fingerprint,
                "class_points": counts.tolist(),
                **({"sensor_reference": reference} if reference else {}),
                "val_root": str(self.val_reader.root),
                "val_sequences": list(val_sequences),
                "frames": [volume_name(v) for v in self.train_vols],
                **({"val_frames": [volume_name(v) for v in self.val_vols]} if self.cfg.holdout else {}),
                **({"init_from": source} if source else {}),
                **({"stream": reader.record()} if stream else {}),
            },
            epochs={},
            metrics=[],
        )

    # -- the schedule (the skeleton's hooks) ------------------------------------------------
    def schedule(self) -> list[str]:
        return self.stages

    def epochs_of(self, stage: str) -> int:
        return self.cfg.epochs.get(stage, 0)

    def run_stage(self, stage: str, done: int, total: int, on_step: StepCallback | None) -> None:
        """The shifting MLPs train their own way; the other stages are the skeleton's loop."""
        if stage == "shift":
            self._run_shift(done, total)
        else:
            super().run_stage(stage, done, total, on_step)

    def before_stage(self, stage: str, done: int) -> None:
        if self.cfg.patience and done == 0:
            stage_start(self, stage)

    def after_epoch(self, stage: str, epoch: int, total: int) -> bool:
        return bool(self.cfg.patience) and early_stop(self, stage, epoch, total)

    def valid_epochs(self, stage: str) -> int:
        """Completed epochs of ``stage`` that still hold: those recorded after the last epoch of an
        earlier stage. Training the backbone again (more semantic epochs after the instance head or
        shifting were trained) invalidates what was trained on the old features; the card's count
        is corrected and the stage starts over from its current weights."""
        earlier = set(STAGES[: STAGES.index(stage)])
        last = max((i for i, m in enumerate(self.card.metrics) if m["stage"] in earlier), default=-1)
        valid = sum(1 for m in self.card.metrics[last + 1 :] if m["stage"] == stage)
        recorded = self.card.epochs.get(stage, 0)
        if valid < recorded:
            log.info(
                "%d %s epoch(s) were trained on an older backbone: retraining the stage from epoch %d",
                recorded,
                stage,
                valid,
            )
            self.card.epochs[stage] = valid
        return min(valid, recorded)

    def _run_shift(self, done: int, total: int) -> None:
        """Train the shifting MLPs (everything else frozen); weights go to ``CKPT/shift.safetensors``.

        Data-parallel like the other stages: each rank collects the seeds of its part of the
        training volumes and draws one of its own samples per step (so a step of W ranks averages W
        samples' gradients and an epoch has ``ceil(samples / W)`` steps); the validation error is
        gathered in volume order."""
        for p in self.model.parameters():
            p.requires_grad_(False)
        # initial weights from the run's seed, not from whatever this process drew before: a run
        # resumed at this stage has not trained the earlier ones and would start (and end) elsewhere
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(
                int(np.random.default_rng([self.cfg.seed, STAGE_SEED["shift"]]).integers(2**31))
            )
            module = make_shift_module(self.cfg.scans, self.model.config.ins_dim)
        saved = load_shift_weights(self.out) if done else None
        if saved is not None:
            module.load_state_dict(saved)
        n_seeds = clusterer_for(self.cfg.scans).n_seeds
        if isinstance(self.reader, StreamLog):  # seeds of the shift stage's own window
            self.train_vols = self.reader.volumes(self.reader.window(STAGE_SEED["shift"], 0))
        log.info("shift stage: collecting seeds of %d training volumes", len(self.train_vols))
        mine = [self.train_vols[i] for i in self.dist.part(len(self.train_vols))]
        train = shift_samples(self.model, self.reader, mine, self.label_map, n_seeds, self.device)
        val_mine = [self.val_vols[i] for i in self.dist.part(len(self.val_vols))]
        val = shift_samples(self.model, self.val_reader, val_mine, self.label_map, n_seeds, self.device)
        counts = self.dist.all_gather(len(train))
        if not sum(counts):
            raise ConfigError("the shift stage needs training volumes with thing instances")
        if not all(counts):
            raise ConfigError(
                f"the shift stage on {self.dist.world_size} processes: process(es) "
                f"{[r for r, c in enumerate(counts) if not c]} have no training volume with thing "
                "instances in their part; train the shift stage with fewer processes"
            )
        steps = -(-sum(counts) // self.dist.world_size)  # one pass over the samples of all ranks
        seed = self.cfg.seed * 1000
        last_miou = next(
            (m["val_miou"] for m in reversed(self.card.metrics) if "val_miou" in m), float("nan")
        )
        for epoch in range(done, total):
            t0 = time.perf_counter()
            losses = train_shift(
                module,
                train,
                steps=steps,
                lr=self.cfg.lr,
                seed=[seed + epoch, self.dist.rank] if self.dist.active else seed + epoch,
                device=str(self.device),
                wrap=lambda m: self.dist.wrap(m, self.device),
            )
            self.dist.sync_buffers(module)  # rank 0's batch-norm statistics, saved and validated
            record = {"stage": "shift", "epoch": epoch + 1, "train_loss": self.mean_loss(losses)}
            record["val_miou"] = last_miou
            errors = np.concatenate(self.dist.all_gather(shift_errors(module, val, self.device)))
            record["val_shift_l1"] = float(np.mean(errors)) if len(errors) else float("nan")
            record["seconds"] = round(time.perf_counter() - t0, 2)
            self.end_epoch("shift", epoch + 1, record, None, shift=module)

    def optimizer(self, stage: str) -> torch.optim.Optimizer:
        """Adam over the stage's parameters: offset the instance head, semantic everything else
        (or only the semantic head with ``freeze_backbone``), joint both."""
        for name, p in self.model.named_parameters():
            instance = name.startswith(INSTANCE_PARAMS)
            semantic = name.startswith("sem_head.") if self.cfg.freeze_backbone else not instance
            p.requires_grad_({"offset": instance, "semantic": semantic, "joint": instance or semantic}[stage])
        params = [p for p in self.model.parameters() if p.requires_grad]
        return torch.optim.Adam(params, lr=self.cfg.lr)

    def train_modes(self, stage: str) -> None:
        self.model.train()
        if stage == "offset":  # frozen backbone: batch-norm statistics stay fixed
            for mod in (self.model.point_encoder, self.model.backbone, self.model.sem_head):
                mod.eval()
        elif self.cfg.freeze_backbone:
            self.model.point_encoder.eval()
            self.model.backbone.eval()

    def epoch_plan(self, stage: str, epoch: int) -> EpochPlan:
        """The epoch's volumes in a seeded order (a stream's its own never-seen window), each
        loaded and augmented as its step comes."""
        stage_idx = STAGE_SEED[stage]
        if isinstance(self.reader, StreamLog):  # never-seen samples, a function of (stage, epoch)
            self.train_vols = self.reader.volumes(self.reader.window(stage_idx, epoch))
        load = self._sample
        if self.real is not None:  # a share of the samples mixed with real volumes (own stream)
            load = self._real_loader([self.cfg.seed, stage_idx, epoch, REAL_STREAM])
        plan = self.shuffled_plan([self.cfg.seed, stage_idx, epoch], len(self.train_vols), load)
        if isinstance(self.reader, StreamLog):
            self.reader.prefetch([self.train_vols[i][-1].sequence for i in plan.order])
        return plan

    def _real_loader(self, key: list[int]):
        """``load(i, rng)``: the synthetic sample ``i`` as without ``--real``, then mixed with a real
        volume or not, by draws of the stream ``key`` (the rank's own under torchrun)."""
        assert self.real is not None
        real, rng_real = self.real, np.random.default_rng([*key, self.dist.rank])

        def load(i: int, rng: np.random.Generator) -> Sample:
            return real.draw(self._sample(i, rng), rng_real, rng_real if self.cfg.augment else None)

        return load

    def _sample(self, i: int, rng: np.random.Generator) -> Sample:
        s = load_sample(self.reader, self.train_vols[i], self.label_map)
        return _with_points(s, augment(s.points, rng)) if self.cfg.augment else s

    def loss(
        self, stage: str, batch: list[Sample], net: torch.nn.Module | None = None, rng=None
    ) -> torch.Tensor:
        """The stage's loss: semantic, offset (eq. 1, or eq. 9 when equivariant) or their sum (joint)."""
        clouds = [torch.from_numpy(s.points).to(self.device) for s in batch]
        out = (self.model if net is None else net)(clouds, instance=stage != "semantic")
        if stage == "semantic":
            return self._semantic_loss(out, batch)
        loss = self._offset_loss(out, clouds, batch)
        return loss + self._semantic_loss(out, batch) if stage == "joint" else loss

    def _semantic_loss(self, out: NetOutput, samples: list[Sample]) -> torch.Tensor:
        sem = torch.from_numpy(np.concatenate([s.sem for s in samples])).to(self.device)
        n_vox, n_cls = out.voxel_logits.shape
        vsem = voxel_labels(out.point_to_voxel, sem, n_vox, n_cls)
        return semantic_loss(out.voxel_logits, vsem, self.weights)

    def _offset_loss(self, out: NetOutput, clouds: list[torch.Tensor], samples: list[Sample]) -> torch.Tensor:
        xyz = torch.cat([c[:, :3] for c in clouds])
        keys = np.concatenate([s.inst + (b << 40) * (s.inst > 0) for b, s in enumerate(samples)])
        valid = torch.from_numpy(np.concatenate([s.thing for s in samples])).to(self.device)
        if any(s.centre is not None for s in samples):  # centres fixed before mixing
            fixed = [s.centre if s.centre is not None else centres_of(s) for s in samples]
            centres = torch.from_numpy(np.concatenate(fixed)).to(self.device, xyz.dtype)
        else:
            centres = instance_centres(xyz, torch.from_numpy(keys).to(self.device), valid)
        if out.anchor_scores is not None:  # equivariant: eq. 9 + the offset in the anchor's frame
            return equivariant_offset_loss(out.anchor_scores, out.anchor_offsets, xyz, centres, valid)
        return offset_loss(out.offsets, xyz, centres, valid)

    # -- validation and files --------------------------------------------------------------
    def validate(self, stage: str | None = None) -> dict:
        """Point mIoU (classes 1..C-1) and the eq. 1 offset error (metres) on the validation volumes.

        Under torchrun each rank scores its part of the volumes; the confusion matrices are summed
        and the offset errors summed in volume order, so every rank gets the single process's
        numbers, bit for bit."""
        self.model.eval()
        meter = ConfusionMeter(self.model.config.num_classes)
        rows = []  # per volume with thing points: (mean offset L1 in metres, thing points)
        with torch.inference_mode():
            for i in self.dist.part(len(self.val_vols)):
                s = load_sample(self.val_reader, self.val_vols[i], self.label_map)
                pts = torch.from_numpy(s.points).to(self.device)
                out = self.model([pts])
                pred = (out.logits[:, 1:].argmax(1) + 1).cpu().numpy()
                meter.add(pred, s.sem)
                if s.thing.any():
                    valid = torch.from_numpy(s.thing).to(self.device)
                    centres = instance_centres(pts[:, :3], torch.from_numpy(s.inst).to(self.device), valid)
                    l1 = float(offset_loss(out.offsets, pts[:, :3], centres, valid))
                    rows.append((l1, int(valid.sum())))
        parts = self.dist.all_gather((meter.conf, rows))
        meter.conf = sum(conf for conf, _ in parts)
        off_sum, off_n = 0.0, 0
        for l1, n in (row for _, part in parts for row in part):
            off_sum += l1 * n
            off_n += n
        iou = meter.iou()
        names = self.label_map.class_names
        return {
            "val_miou": meter.miou(),
            "val_offset_l1": off_sum / off_n if off_n else float("nan"),
            "val_iou": {names[c]: float(iou[c]) for c in range(1, len(iou)) if np.isfinite(iou[c])},
        }

    def write_checkpoint(self, staging: Path, stage: str, extra: dict) -> None:
        """The weights and card, with the shifting weights: the epoch's new ones (``extra["shift"]``)
        or the folder's current ones (the card covers the shifting weights it sits with)."""
        shift = extra.get("shift")
        if shift is not None:
            save_shift_weights(staging, shift)
        elif (self.out / SHIFT_WEIGHTS).is_file():
            shutil.copyfile(self.out / SHIFT_WEIGHTS, staging / SHIFT_WEIGHTS)
        save_checkpoint(staging, self.model, self.card)


def _with_points(s: Sample, points: np.ndarray) -> Sample:
    return Sample(points, s.sem, s.inst, s.thing, s.frame_index, s.name)
