"""Fine-tuning on a few corrected frames (5–50): a seeded held-back validation part and early
stopping that keeps the best epoch's weights.

The weights a stage starts from count as its epoch 0: a stage that never beats them (an instance
head over-fitting four frames) ends with the weights it started from. The best weights of a running
stage are kept in ``CKPT/best_<stage>.safetensors`` so that an interrupted run resumes with them;
the card's ``training_data["early_stop"][stage]`` records the best epoch (0 = the incoming
weights), the epoch the stage ended after and the score. Under torchrun rank 0 writes that file and
every rank reads it back.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
from safetensors.torch import load_file

from dsnet_core.io.reader import FrameRef
from dsnet_core.model.checkpoint import save_tensors

if TYPE_CHECKING:
    from dsnet_core.train.loop import Trainer

#: per stage: the validation score and whether higher is better
SCORES = {"semantic": ("val_miou", True), "offset": ("val_offset_l1", False), "joint": ("val_miou", True)}


def volume_name(refs: list[FrameRef]) -> str:
    """``"SS/NNNNNN"`` of a volume's reference (last) frame."""
    return f"{refs[-1].sequence}/{refs[-1].frame_id}"


def holdout_split(
    volumes: list[list[FrameRef]], fraction: float, seed: int
) -> tuple[list[list[FrameRef]], list[list[FrameRef]]]:
    """Hold back ``round(fraction · n)`` volumes (at least 1 when n ≥ 2, never all) for validation.

    Returns:
        (training volumes, held-back volumes), each in the input order; the choice depends only on
        ``seed`` and the volumes' names.
    """
    n = len(volumes)
    k = min(n - 1, max(1 if n >= 2 else 0, round(fraction * n)))
    names = sorted(volume_name(v) for v in volumes)
    chosen = set(np.random.default_rng([seed, n]).permutation(names)[:k].tolist())
    train = [v for v in volumes if volume_name(v) not in chosen]
    return train, [v for v in volumes if volume_name(v) in chosen]


def stage_start(trainer: Trainer, stage: str) -> None:
    """Before a stage's first epoch: score the incoming weights (epoch 0) and keep them as the best."""
    name, _ = SCORES[stage]
    trainer.card.training_data.setdefault("stage_start", {})[stage] = float(trainer.validate()[name])
    if trainer.dist.is_main:
        trainer.out.mkdir(parents=True, exist_ok=True)
        save_tensors(trainer.model.state_dict(), trainer.out / f"best_{stage}.safetensors")


def early_stop(trainer: Trainer, stage: str, epoch: int, total: int) -> bool:
    """After ``epoch`` (1-based) of ``stage``: keep the best weights; True when the stage should stop.

    At the stage's end or when ``trainer.cfg.patience`` epochs passed without a better score, the
    best epoch's weights go back into the model and the checkpoint.
    """
    name, higher = SCORES[stage]
    records = [m for m in trainer.card.metrics if m["stage"] == stage][-epoch:]
    start = trainer.card.training_data.get("stage_start", {}).get(stage, math.nan)
    scores = [float(start)] + [float(m.get(name, math.nan)) for m in records]
    key = [(-s if higher else s) if math.isfinite(s) else math.inf for s in scores]
    best = int(np.argmin(key))  # the first best epoch; 0 = the weights the stage started from
    best_file = trainer.out / f"best_{stage}.safetensors"
    if best == epoch and trainer.dist.is_main:
        save_tensors(trainer.model.state_dict(), best_file)
    if epoch - best < trainer.cfg.patience and epoch < total:
        return False
    trainer.dist.barrier()  # rank 0's best weights are on disk for every rank
    if best != epoch and best_file.is_file():
        trainer.model.load_state_dict(load_file(str(best_file), device=str(trainer.device)))
    trainer.card.training_data.setdefault("early_stop", {})[stage] = {
        "best_epoch": best,
        "stopped_after": epoch,
        "score": name,
        "value": scores[best],
    }
    trainer.save(stage, epoch, None)  # weights, card and metrics land together
    if trainer.dist.is_main:
        best_file.unlink(missing_ok=True)
    return epoch < total
