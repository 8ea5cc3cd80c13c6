"""Fine-tuning on a few corrected frames under a synthetic domain shift (sensor HDL-64 → VLP-32).

A model trained on one domain (default: the bundled ``tiny``, trained on HDL-64 synthetic logs) is
fine-tuned on N corrected frames of the other (ground truth stands in for the corrections), for
each N; every model, and optionally one trained on the second domain from the start, is labelled
(``dsnet label --scans 1``), exported and scored (``dsnet eval``, official mode) on held-out
sequences of the second domain. Resumable: finished fine-tunes and scores are reused.

    PYTHONPATH=. .venv/bin/python bench/finetune_domain_shift.py --data vlp-train \\
        --pool 00,01,02,03 --heldout vlp-heldout --ns 5,10,20 --scratch scratch --out ft-exp
"""

from __future__ import annotations

import argparse
import json
import logging
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import torch

from dsnet_core.checkpoints import bundled_checkpoint
from dsnet_core.io.semantickitti import SemanticKittiReader
from dsnet_core.labels import load_label_map
from dsnet_core.model.checkpoint import read_card
from dsnet_core.model.presets import get_preset
from dsnet_core.review.folder import ReviewFrame, write_review_folder
from dsnet_core.train.loop import TrainConfig, Trainer

DSNET = [sys.executable, "-m", "flows.cli"]


def corrected_frames(data: Path, pool: list[str], n: int, out: Path) -> Path:
    """N frames spread evenly over the pool sequences, with their ground truth as the correction."""
    if (out / "review.json").is_file():
        return out
    reader = SemanticKittiReader(data)
    refs = [r for s in pool for r in reader.frames(s)]
    step = len(refs) / n
    chosen = [refs[int(i * step)] for i in range(n)]
    frames = [ReviewFrame(r.sequence, r.frame_id, reader.scan(r), reader.labels(r)) for r in chosen]
    return write_review_folder(out, frames, {"data": str(data), "correction": "ground truth"})


def fine_tune(source: Path, frames: Path, out: Path, args) -> float:
    """Fine-tune ``source`` on ``frames`` into ``out``; wall seconds of this call (0 when done)."""
    label_map = load_label_map("semantic-kitti")
    reader = SemanticKittiReader(frames)
    cfg = TrainConfig(
        stage="all",
        epochs={"semantic": args.semantic_epochs, "offset": args.offset_epochs, "shift": 0},
        lr=args.lr,
        holdout=0.2,
        patience=args.patience,
        freeze_backbone=args.freeze_backbone,
        seed=0,
    )
    resume = (out / "card.json").is_file()
    t0 = time.perf_counter()
    seqs = reader.sequences()
    trainer = Trainer(out, get_preset("tiny"), reader, seqs, reader, seqs, label_map, cfg, resume, source)
    trainer.run()
    return time.perf_counter() - t0


def score(ckpt: Path, heldout: Path, work: Path, name: str) -> dict:
    """Label, export and score ``heldout`` with ``ckpt`` (cached in ``work/scores/NAME.json``)."""
    out = work / "scores" / f"{name}.json"
    if out.is_file():
        return json.loads(out.read_text())
    seqs = ",".join(SemanticKittiReader(heldout).sequences())
    run, pred = work / "runs" / name, work / "preds" / name
    for cmd in (
        [*DSNET, "label", str(heldout), "--run", str(run), "--scans", "1", "--checkpoint", str(ckpt)],
        [*DSNET, "export", str(run), "--out", str(pred)],
        [*DSNET, "eval", "--gt", str(heldout), "--pred", str(pred), "--sequences", seqs, "--json", str(out)],
    ):
        subprocess.run(cmd, check=True, capture_output=True)
    return json.loads(out.read_text())


def summary(result: dict) -> dict:
    pan = result.get("panoptic", result)
    return {k: pan.get(k) for k in ("pq", "pq_things", "pq_stuff", "miou")}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--data", type=Path, required=True, help="second-domain log holding the corrected frames")
    p.add_argument("--pool", default=None, help="sequences of --data to draw frames from (default: all)")
    p.add_argument("--heldout", type=Path, required=True, help="second-domain log to score on")
    p.add_argument(
        "--source", type=Path, default=None, help="first-domain checkpoint (default: bundled tiny)"
    )
    p.add_argument("--scratch", type=Path, default=None, help="checkpoint trained on the second domain")
    p.add_argument("--ns", default="5,10,20")
    p.add_argument("--semantic-epochs", type=int, default=12)
    p.add_argument("--offset-epochs", type=int, default=6)
    p.add_argument("--patience", type=int, default=3)
    p.add_argument("--lr", type=float, default=1e-3)
    p.add_argument("--freeze-backbone", action="store_true")
    p.add_argument("--out", type=Path, required=True)
    args = p.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    torch.set_num_threads(1)
    source = args.source or bundled_checkpoint(1)
    pool = args.pool.split(",") if args.pool else SemanticKittiReader(args.data).sequences()
    args.out.mkdir(parents=True, exist_ok=True)
    times_file = args.out / "wall_seconds.json"
    walls = json.loads(times_file.read_text()) if times_file.is_file() else {}
    rows = {"source (first domain)": summary(score(source, args.heldout, args.out, "source"))}
    tag = "freeze" if args.freeze_backbone else "all"
    for n in (int(v) for v in args.ns.split(",")):
        frames = corrected_frames(args.data, pool, n, args.out / f"frames-{n}")
        ckpt = args.out / f"ft-{tag}-{n}"
        spent = fine_tune(source, frames, ckpt, args)
        walls[str(ckpt.name)] = walls.get(str(ckpt.name), 0.0) + spent
        times_file.write_text(json.dumps(walls, indent=2))
        card = read_card(ckpt)
        row = summary(score(ckpt, args.heldout, args.out, ckpt.name))
        row["wall_s"] = round(walls[ckpt.name], 1)
        row["epochs"] = card.epochs
        row["early_stop"] = {k: v["best_epoch"] for k, v in card.training_data.get("early_stop", {}).items()}
        rows[f"fine-tuned N={n} ({tag})"] = row
    if args.scratch is not None:
        rows["trained on the second domain"] = summary(score(args.scratch, args.heldout, args.out, "scratch"))
    (args.out / f"results-{tag}.json").write_text(json.dumps(rows, indent=2))
    print(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
