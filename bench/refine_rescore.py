"""Refine on vs off again on finished run stores, without running a model: each store's temporal
stage labels (and the model's probabilities) are read back, refined in memory with the current
code and the settings given, and both are scored against the log's ground truth.

A store of ``bench/bench_transfer.py --refine`` (``DIR/<model>/<cell>/<row>/<method>``) reproduces
its "before refine" and "scores" rows exactly with the settings it ran with; ``--set`` changes
refine's settings (``RefineConfig`` fields) on top of the store's. Seconds per cell, one thread.

Run: ``OMP_NUM_THREADS=1 .venv/bin/python bench/refine_rescore.py STORE [STORE ...]
[--set class_margin=0] [--json OUT]``. Cells whose name starts with ``seeds``, ``styles`` or
``sensors`` (``dsnet synth``) are averaged apart from the rest (the other generator, PandaSet:
reported, never selected on).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from dsnet_core.refine import ClassSets, refine_sequence  # noqa: E402
from dsnet_core.refine.frame import encode_labels  # noqa: E402
from storage.run import RunStore  # noqa: E402
from tasks.refine import FrameLoader, RefineConfig, probability_sources, refine_params  # noqa: E402
from tasks.run_config import read_run  # noqa: E402
from tasks.runner import make_context  # noqa: E402
from tasks.score import make_evaluator  # noqa: E402

SYNTH = ("seeds", "styles", "sensors")
KEYS = ("pq", "pq_things", "pq_stuff", "miou", "lstq")


def _value(text: str):
    return None if text == "None" else json.loads(text) if text[:1] in "0123456789-tf[" else text


def rescore(root: str, overrides: dict) -> dict:
    """``{"before": scores, "after": scores, "things_iou": (before, after)}`` of one store."""
    store = RunStore(root)
    run = read_run(store)
    pipe = run.pipeline()
    before = after = None
    for seq in store.sequences():
        ctx = make_context(store, pipe, seq, "refine", run)
        stage = pipe["refine"]
        probs, align = probability_sources(pipe, "refine")
        load = FrameLoader(ctx, stage.labels, probs, align)
        t = ctx.frames.to_pydict()
        done = ctx.arrays(stage.labels).done()
        frames = [
            load(int(i)) for i, s in zip(t["index"], t["status"], strict=True) if s == "ok" and done[int(i)]
        ]
        config = RefineConfig.model_validate({**ctx.config.model_dump(), **overrides})
        lm = ctx.label_map
        out = refine_sequence(
            frames, ClassSets.from_label_map(lm), refine_params(config), stage._confidence(ctx)
        )
        sctx = make_context(store, pipe, seq, "score", run)
        if before is None:
            before = make_evaluator(sctx.config, ctx.reader.label_map, lm)
            after = make_evaluator(sctx.config, ctx.reader.label_map, lm)
        refs = ctx.reader.frames(seq)
        for f, o in zip(frames, out, strict=True):
            gt = ctx.reader.labels(refs[f.index])
            before.add(gt, encode_labels(f.sem, f.inst, lm), frame=str(f.index), sequence=seq)
            after.add(gt, encode_labels(o.sem, o.inst, lm), frame=str(f.index), sequence=seq)
    rb, ra = before.result(), after.result()
    gt_map = ctx.reader.label_map
    things = [
        gt_map.class_names[c] for c in gt_map.things if rb.classes[gt_map.class_names[c]]["gt_points"] > 0
    ]
    iou = [
        float(np.mean([r.classes[c]["iou"] for c in things])) if things else float("nan") for r in (rb, ra)
    ]
    return {
        "before": {k: rb.scores()[k] for k in KEYS},
        "after": {k: ra.scores()[k] for k in KEYS},
        "things_iou": iou,
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("stores", nargs="+")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--json", type=Path)
    args = ap.parse_args(argv)
    overrides = {k: _value(v) for k, v in (s.split("=", 1) for s in args.set)}
    rows = {}
    print("| cell | PQ | PQ^Th | PQ^St | mIoU | mIoU things present | LSTQ |")
    print("|---|---|---|---|---|---|---|")
    for root in args.stores:
        parts = Path(root).resolve().parts
        name = f"{parts[-3]}:{parts[-2]}"
        r = rows[name] = rescore(root, overrides)
        b, a, ti = r["before"], r["after"], r["things_iou"]
        cols = [f"{b[k]:.3f} → {a[k]:.3f}" for k in KEYS[:4]]
        print(
            f"| {name} | {' | '.join(cols)} | {ti[0]:.3f} → {ti[1]:.3f} | {b['lstq']:.3f} → {a['lstq']:.3f} |"
        )
    for group, names in (
        ("dsnet synth", [n for n in rows if n.startswith(SYNTH)]),
        ("other generator + PandaSet", [n for n in rows if not n.startswith(SYNTH)]),
    ):
        if names:
            gain = {k: np.mean([rows[n]["after"][k] - rows[n]["before"][k] for n in names]) for k in KEYS[:2]}
            iou = np.mean([rows[n]["things_iou"][1] - rows[n]["things_iou"][0] for n in names])
            print(f"mean gain over {len(names)} {group} cells: PQ {gain['pq']:+.4f}, "
                  f"PQ^Th {gain['pq_things']:+.4f}, mIoU things {iou:+.4f}")  # fmt: skip
    if args.json:
        args.json.write_text(json.dumps({"set": overrides, "cells": rows}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
