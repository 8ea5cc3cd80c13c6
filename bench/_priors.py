"""Prior directories for the D-PLS rows of the method benchmarks: a log's ground truth written as
per-scan prior files (``DIR/SEQ/ID.label``), clean or corrupted by
:mod:`dsnet_core.train.prior_noise` (the bundled D-PLS card's measured confusion, scaled by a
factor found by bisection so that the prior's mIoU over the whole log hits a target)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np


def _frames(log: Path):
    from dsnet_core.io.semantickitti import SemanticKittiReader
    from dsnet_core.labels import load_label_map

    lm = load_label_map("semantic-kitti")
    reader = SemanticKittiReader(log)
    for seq in reader.sequences():
        for ref in reader.frames(seq):
            label = reader.labels(ref)
            sem = lm.to_train(label & 0xFFFF).astype(np.int64)
            ids = (label >> 16).astype(np.int64)
            inst = np.where((ids > 0) & lm.is_thing()[sem], (sem << 32) | ids, 0)
            yield seq, ref, reader.scan(ref)[:, :3], sem, inst, label, lm


def _corrupt(log: Path, scale: float, seed: int) -> list[tuple]:
    from dsnet_core.checkpoints import DPLS
    from dsnet_core.model.checkpoint import read_card
    from dsnet_core.train.prior_noise import PriorNoise, corrupt_prior, scale_confusion

    card = read_card(DPLS.bundled())
    confusion = scale_confusion(np.asarray(card.training_data["prior_noise"]["confusion"]), scale)
    noise = PriorNoise(confusion, strength=(0.0, 0.0))
    out = []
    for i, (seq, ref, xyz, sem, inst, label, lm) in enumerate(_frames(log)):
        pred = corrupt_prior(xyz, sem, inst, noise, np.random.default_rng([seed, i]))
        out.append((seq, ref, sem, pred, label, lm))
    return out


def _miou(frames: list[tuple]) -> float:
    from dsnet_core.train.metrics import ConfusionMeter

    meter = ConfusionMeter(frames[0][-1].num_classes)
    for _, _, sem, pred, _, _ in frames:
        meter.add(pred, sem)
    return float(meter.miou())


def write_prior(log: Path, out: Path, target_miou: float | None = None, seed: int = 0) -> dict:
    """Write the prior directory (skipped when already there); returns its record (achieved mIoU)."""
    stamp = out / "prior.json"
    want = {"log": str(Path(log).resolve()), "target_miou": target_miou, "seed": seed}
    if stamp.exists():
        rec = json.loads(stamp.read_text())
        if {k: rec.get(k) for k in want} == want:
            return rec
    if target_miou is None:
        frames = [(s, r, sem, sem, lab, lm) for s, r, _, sem, _, lab, lm in _frames(log)]
        scale = 0.0
    else:
        lo, hi = 0.0, 8.0
        for _ in range(8):  # mIoU falls as the confusion's off-diagonal mass grows
            scale = 0.5 * (lo + hi)
            frames = _corrupt(log, scale, seed)
            lo, hi = (scale, hi) if _miou(frames) > target_miou else (lo, scale)
    for seq, ref, _, pred, label, lm in frames:
        d = out / seq
        d.mkdir(parents=True, exist_ok=True)
        raw = lm.to_raw(pred) if target_miou is not None else label & 0xFFFF
        np.asarray(raw, np.uint32).tofile(d / f"{ref.frame_id}.label")
    rec = {**want, "scale": scale, "miou": _miou(frames)}
    stamp.write_text(json.dumps(rec) + "\n")
    return rec
