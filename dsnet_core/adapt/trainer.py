"""Self-training a DS-Net model on unlabelled target logs, on the shared trainer skeleton.

Each round is a stage of the skeleton (``round1``, ``round2``, …) with ``epochs`` epochs; the
skeleton runs the steps, this module supplies the mixed scans, the loss and the EMA step. Before a
round's first epoch the teacher (the parent in round 1, then the EMA teacher of the round before,
snapshotted in ``CKPT/rounds/R/teacher``) labels the target logs and the labeller selects the
pseudo-labels (:class:`~dsnet_core.adapt.config.Labeller`). Every student step trains on one scan
of a target/source pair mixed by inclination bands or an azimuth sector
(:mod:`dsnet_core.adapt.mixing`; a pair gives two steps), then moves the teacher towards the
student (:func:`~dsnet_core.adapt.ema.ema_update`). Corrected frames join the target pool with
their true labels and a higher weight.

The checkpoint folder holds the teacher as the model (``model.safetensors`` + ``card.json``: what
``dsnet label --checkpoint CKPT`` uses), the parent's shifting MLPs, the student
(``student.safetensors``) and its optimiser state; every epoch is committed as a whole, so a SIGKILL
resumes to the weights an uninterrupted run ends with (each round restarts Adam; the order,
augmentation, mixing and source samples of an epoch depend on (seed, round, epoch) only).
"""

from __future__ import annotations

import copy
import logging
import os
import shutil
from dataclasses import asdict
from pathlib import Path

import numpy as np
import torch
from safetensors import SafetensorError
from safetensors.torch import load_file

from dsnet_core.adapt import stopping
from dsnet_core.adapt.config import MIN_HELDOUT, AdaptConfig, Labeller
from dsnet_core.adapt.data import Item, load_cloud
from dsnet_core.adapt.ema import ema_update
from dsnet_core.adapt.losses import adapt_loss
from dsnet_core.adapt.mixing import mix_pair
from dsnet_core.adapt.source import Source, cycled
from dsnet_core.errors import CheckpointError, ConfigError
from dsnet_core.labels import LabelMap
from dsnet_core.model.bundle import SHIFT_WEIGHTS
from dsnet_core.model.checkpoint import (
    CARD,
    WEIGHTS,
    ModelCard,
    code_version,
    load_checkpoint,
    save_checkpoint,
    save_tensors,
    sha256_file,
)
from dsnet_core.model.losses import class_weights
from dsnet_core.train.metrics import ConfusionMeter
from dsnet_core.train.skeleton import EpochPlan, StepConfig, TrainerSkeleton, prepare_out

log = logging.getLogger(__name__)
STUDENT = "student.safetensors"
ROUNDS = "rounds"
METRIC_COLUMNS = (
    "stage",
    "epoch",
    "lr",
    "train_loss",
    "val_source_miou",
    "val_heldout_miou",
    "val_agreement",
    "seconds",
)


def round_name(r: int) -> str:
    return f"round{r}"


def round_of(stage: str) -> int:
    return int(stage.removeprefix("round"))


class AdaptTrainer(TrainerSkeleton):
    """Adapts ``parent`` to the target logs.

    Args:
        out: checkpoint folder.
        parent: the checkpoint adaptation starts from (a DS-Net one).
        config: the schedule.
        labeller: makes each round's pseudo-labels with a teacher checkpoint.
        source: the source scans of the mixed pairs.
        corrected: corrected frames trained on (true labels, ``config.label_weight``).
        heldout: held-back corrected frames (validation; early stopping with ≥ 3).
        source_val: the source probe (true labels): does the teacher forget the source?
        label_map: the class map (the parent's must equal it).
        record: what the card records of the run besides the schedule (logs, thresholds' settings).
        resume: continue the checkpoint in ``out``.
    """

    stage_names = ()
    metric_columns = METRIC_COLUMNS

    def __init__(
        self,
        out: str | Path,
        parent: str | Path,
        config: AdaptConfig,
        labeller: Labeller,
        source: Source,
        corrected: list[Item],
        heldout: list[Item],
        source_val: list[Item],
        label_map: LabelMap,
        record: dict,
        resume: bool = False,
    ) -> None:
        self.out, self.parent, self.cfg, self.labeller = Path(out), Path(parent), config, labeller
        self.source, self.corrected, self.heldout, self.source_val = source, corrected, heldout, source_val
        self.label_map, self.device = label_map, torch.device(config.device)
        self.step = StepConfig.of(config)  # lr, its schedule and floor; one scan per step
        self.pool: list[Item] = []
        self.targets: list[Item] = []
        if prepare_out(self.out, resume):
            self.teacher, self.card = load_checkpoint(self.out, self.device, expect_label_map=label_map)
            self._check_resume()
            self.model = copy.deepcopy(self.teacher)
            self.model.load_state_dict(self._student_state())
        else:
            self.teacher, parent_card = load_checkpoint(self.parent, self.device, expect_label_map=label_map)
            if parent_card.config.prior_channels or not parent_card.config.semantic_head:
                raise ConfigError(
                    f"{self.parent} is not a DS-Net checkpoint with a semantic head: it cannot adapt"
                )
            self.model = copy.deepcopy(self.teacher)
            self.card = self._new_card(parent_card, record)
        self.card.training_data["adapt"]["config"] = asdict(config)
        self.card.training_data["adapt"]["stopping"] = self._stopping()
        self.card.code_version = code_version()
        self.teacher.eval()
        counts = self.card.training_data.get("class_points")
        self.class_weights = class_weights(np.asarray(counts)).to(self.device) if counts else None

    def _new_card(self, parent_card: ModelCard, record: dict) -> ModelCard:
        return ModelCard(
            architecture=parent_card.architecture,
            class_map=parent_card.class_map,
            training_data={
                "adapt": {
                    **record,
                    "parent": {
                        "path": str(self.parent.resolve()),
                        "weights_sha256": parent_card.weights_sha256,
                    },
                    "rounds": [],
                },
                "init_from": {
                    "path": str(self.parent.resolve()),
                    "weights_sha256": parent_card.weights_sha256,
                },
                "class_points": parent_card.training_data.get("class_points"),
                "scans": self.cfg.scans,
                "source": self.source.record(),
            },
            epochs={},
            metrics=[],
        )

    def _check_resume(self) -> None:
        adapt = self.card.training_data.get("adapt")
        if adapt is None:
            raise ConfigError(f"{self.out} holds a checkpoint that adapt did not write: choose another --out")
        changed = self.cfg.changed(adapt.get("config", {}))
        if changed:
            raise ConfigError(
                f"{self.out}: resume with the settings it was started with ({'; '.join(changed)})"
            )

    def _stopping(self) -> str:
        n = len(self.heldout)
        if n >= MIN_HELDOUT and self.cfg.patience:
            return f"held-out early stopping on {n} corrected frames (patience {self.cfg.patience} epochs)"
        return (
            f"fixed budget ({self.cfg.rounds} rounds × {self.cfg.steps} steps), no held-out early stop "
            f"({n} held-back frames < {MIN_HELDOUT} or patience 0); the EMA teacher is written; the "
            "source probe's mIoU and the agreement with the pseudo-labels are recorded per epoch"
        )

    def _early_stopping(self) -> bool:
        return len(self.heldout) >= MIN_HELDOUT and self.cfg.patience > 0

    # -- the skeleton's hooks -----------------------------------------------------------------
    def schedule(self) -> list[str]:
        return [round_name(r) for r in range(1, self.cfg.rounds + 1)]

    def epochs_of(self, stage: str) -> int:
        return self.cfg.epochs

    def stopped_early(self, stage: str, done: int) -> bool:
        return "early_stop" in self.card.training_data["adapt"]

    def optimizer(self, stage: str) -> torch.optim.Optimizer:
        for p in self.model.parameters():
            p.requires_grad_(True)
        return torch.optim.Adam(self.model.parameters(), lr=self.cfg.lr)

    def before_stage(self, stage: str, done: int) -> None:
        """The round's pseudo-labels (labelled by the round's teacher), and the parent's source probe
        and held-out scores before the very first epoch."""
        r = round_of(stage)
        data = self.labeller(r, self.teacher_checkpoint(r))
        if not data.items and not self.corrected:
            raise ConfigError(
                f"round {r}: no pseudo-labelled target frame and no corrected frame to train on"
            )
        self.targets = data.items
        self.pool = data.items + self.corrected
        rounds = self.card.training_data["adapt"]["rounds"]
        del rounds[r - 1 :]
        rounds.append({"round": r, **data.record})
        if not self.card.metrics and done == 0:  # the parent's scores: epoch 0
            self.card.training_data["adapt"]["source_start"] = self._miou(self.source_val)
            if self._early_stopping():
                stopping.start(self)

    def after_epoch(self, stage: str, epoch: int, total: int) -> bool:
        if not self._early_stopping():
            return False
        last = round_of(stage) == self.cfg.rounds and epoch == total
        return stopping.after_epoch(self, stage, epoch, last)

    def teacher_checkpoint(self, r: int) -> Path:
        """The checkpoint that labels round ``r``: the parent, then a snapshot of ``CKPT`` as the
        previous round left it (taken once; a resumed round labels with the same one)."""
        if r == 1:
            return self.parent
        snap = self.out / ROUNDS / str(r) / "teacher"
        if not (snap / CARD).is_file():
            tmp = snap.with_name("teacher.tmp")
            shutil.rmtree(tmp, ignore_errors=True)
            tmp.mkdir(parents=True)
            for name in (WEIGHTS, SHIFT_WEIGHTS, CARD):
                if (self.out / name).is_file():
                    shutil.copyfile(self.out / name, tmp / name)
            shutil.rmtree(snap, ignore_errors=True)
            os.replace(tmp, snap)
        return snap

    def epoch_plan(self, stage: str, epoch: int) -> EpochPlan:
        """``steps_in(epoch)`` mixed scans: cycled target/source pairs, each mixed into two."""
        r, n = round_of(stage), self.cfg.steps_in(epoch)
        pairs = (n + 1) // 2
        rng = np.random.default_rng([self.cfg.seed, 31, r, epoch])
        torch.manual_seed(int(rng.integers(2**31)))
        targets = [self.pool[i] for i in cycled(rng, len(self.pool), pairs)]
        sources = self.source.items(r, epoch, pairs)
        aug = rng if self.cfg.augment else None

        def batches():
            made = 0
            for t_item, s_item in zip(targets, sources, strict=True):
                t = load_cloud(t_item, self.label_map, aug)
                s = load_cloud(s_item, self.label_map, aug)
                for cloud in mix_pair(t, s, self.cfg.mix, rng)[:2]:
                    if made == n:
                        break
                    made += 1
                    yield [cloud]

        return EpochPlan(n, batches(), rng, np.arange(0))

    def loss(self, stage: str, batch: list, net: torch.nn.Module, rng: np.random.Generator) -> torch.Tensor:
        return adapt_loss(net, batch, self.class_weights, self.device)

    def after_step(self, stage: str) -> None:
        ema_update(self.teacher, self.model, self.cfg.ema)  # the teacher follows every student step

    def after_steps(self, stage: str) -> None:
        self.teacher.eval()

    def validate(self, stage: str | None = None) -> dict:
        """The teacher's mIoU on the source probe and on the held-back corrected frames (NaN with
        fewer than 3), and its agreement with the round's pseudo-labels on the first target frames."""
        source = self._miou(self.source_val)
        heldout = self._miou(self.heldout) if len(self.heldout) >= MIN_HELDOUT else float("nan")
        agree = self._miou(self.targets[: self.cfg.val_target], agreement=True)
        return {"val_source_miou": source, "val_heldout_miou": heldout, "val_agreement": agree}

    def _miou(self, items: list[Item], agreement: bool = False) -> float:
        if not items:
            return float("nan")
        self.teacher.eval()
        meter = ConfusionMeter(self.label_map.num_classes)
        with torch.inference_mode():
            for item in items:
                cloud = load_cloud(item, self.label_map, None)
                out = self.teacher([torch.from_numpy(cloud.points).to(self.device)], instance=False)
                meter.add((out.logits[:, 1:].argmax(1) + 1).cpu().numpy(), cloud.sem)
        if agreement:  # share of pseudo-labelled points the teacher now predicts as labelled
            total = int(meter.conf.sum())
            return float(np.trace(meter.conf) / total) if total else float("nan")
        return meter.miou()

    def write_checkpoint(self, staging: Path, stage: str, extra: dict) -> None:
        """The teacher (weights + card), the parent's shifting MLPs and the student (first: the
        card records its sha256)."""
        shift = self.parent / SHIFT_WEIGHTS
        if shift.is_file():
            shutil.copyfile(shift, staging / SHIFT_WEIGHTS)
        save_tensors(self.model.state_dict(), staging / STUDENT)
        self.card.training_data["adapt"]["student_sha256"] = sha256_file(staging / STUDENT)
        save_checkpoint(staging, self.teacher, self.card)

    def _student_state(self) -> dict[str, torch.Tensor]:
        """The student's weights saved with the folder's last epoch, checked against the card.

        Raises:
            CheckpointError: missing, not the card's (sha256, when recorded), or unreadable.
        """
        file = self.out / STUDENT
        if not file.is_file():
            raise CheckpointError(file, "the student's weights are missing: the adaptation cannot resume")
        recorded = self.card.training_data["adapt"].get("student_sha256")  # older cards have none
        if recorded is not None and sha256_file(file) != recorded:
            raise CheckpointError(
                file, "the student's weights do not match the model card's record (damaged or half-written)"
            )
        try:
            return load_file(str(file), device=str(self.device))
        except (SafetensorError, OSError) as exc:
            raise CheckpointError(file, f"cannot read the student's weights: {exc}") from None
