"""Held-out early stopping of adaptation, over all rounds' epochs: only with at least
:data:`~dsnet_core.adapt.config.MIN_HELDOUT` held-back corrected frames.

The parent's held-back mIoU is epoch 0. After each epoch the teacher's score is compared with the
best so far (kept in ``CKPT/best_teacher.safetensors``, so a resumed run still has it); after
``patience`` epochs without a better one, or after the last epoch of the last round, the best
teacher's weights go back into the checkpoint and no further round runs. The card records it under
``training_data["adapt"]["early_stop"]``.

With fewer held-back frames there is nothing trustworthy to stop on (one or two frames swing by
tenths of mIoU): the run trains its fixed budget (rounds × steps) and the EMA teacher, an average
over the last ~1/(1 − decay) steps, is what it writes.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
from safetensors.torch import load_file

from dsnet_core.model.checkpoint import save_tensors

if TYPE_CHECKING:
    from dsnet_core.adapt.trainer import AdaptTrainer

BEST = "best_teacher.safetensors"
SCORE = "val_heldout_miou"


def record(trainer: AdaptTrainer) -> dict:
    return trainer.card.training_data["adapt"]


def start(trainer: AdaptTrainer) -> None:
    """Before the first epoch: score the parent (epoch 0) and keep it as the best."""
    record(trainer)["heldout_start"] = float(trainer.validate()[SCORE])
    trainer.out.mkdir(parents=True, exist_ok=True)
    save_tensors(trainer.teacher.state_dict(), trainer.out / BEST)


def after_epoch(trainer: AdaptTrainer, stage: str, epoch: int, last: bool) -> bool:
    """After ``epoch`` (1-based) of round ``stage``: True when adaptation should stop."""
    scores = [float(record(trainer).get("heldout_start", math.nan))]
    scores += [float(m.get(SCORE, math.nan)) for m in trainer.card.metrics]
    key = [-s if math.isfinite(s) else math.inf for s in scores]
    best, now = int(np.argmin(key)), len(scores) - 1
    if best == now:
        save_tensors(trainer.teacher.state_dict(), trainer.out / BEST)
    if now - best < trainer.cfg.patience and not last:
        return False
    if best != now and (trainer.out / BEST).is_file():
        trainer.teacher.load_state_dict(load_file(str(trainer.out / BEST), device=str(trainer.device)))
    record(trainer)["early_stop"] = {
        "best_epoch": best,
        "stopped_after": now,
        "score": SCORE,
        "value": scores[best],
        "round": stage,
    }
    trainer.save(stage, epoch, None)
    (trainer.out / BEST).unlink(missing_ok=True)
    return True
