"""DS-Net clustering ablation, learned dynamic shifting vs heuristic clusterers, one script with two
modes (``bench/ablation_clustering.py MODE [options]``):

    oracle  on oracle inputs (no network; the shifting MLPs trained here)
    model   on a trained model's regressed centres, through the label flow

``bench/ablation_clustering.py MODE --help`` prints that mode's description and options (kept
below as ``ORACLE_DOC`` and ``MODEL_DOC``).
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _oracle import LABEL_MAP, score, synth_scans
from _store4d import stitched

from dsnet_core.instance.clustering import (
    BFSClusterer,
    DBSCANClusterer,
    DynamicShiftClusterer,
    HDBSCANClusterer,
    MeanShiftClusterer,
)
from dsnet_core.instance.shifting import DynamicShift
from dsnet_core.io.semantickitti import SemanticKittiReader
from dsnet_core.labels import load_label_map
from dsnet_core.metrics import PanopticEvaluator
from dsnet_core.train.shifting import make_sample, train_shift
from flows.commands.label import run_label
from flows.request import LabelRequest
from flows.server import prefect_api
from storage.run import RunStore
from tasks.methods import stage_configs

ORACLE_DOC = """DS-Net clustering ablation on oracle inputs: learned dynamic shifting vs heuristic clusterers.

Oracle-feature experiment, no network: synthetic HDL-64 logs (``dsnet_core.synth``), ground-truth
semantics, ground-truth box centres plus the regression-noise model of ``dsnet_core.oracle.inputs``, and
32-d oracle features (ground-truth class one-hot + regressed-centre geometry) in place of the
backbone feature. The shifting MLPs are trained on logs of one seed (VLP-32 and HDL-64 scans);
every heuristic's parameters are tuned by grid search on a subset of the VLP-32 training scans;
all are scored (PQ^Th, official SemanticKITTI semantics, project evaluator) on a VLP-32 log of
another seed.

    .venv/bin/python bench/ablation_clustering.py oracle [--save-weights PATH] [--data DIR]
"""

MODEL_DOC = """DS-Net clustering ablation on a trained model: learned dynamic shifting vs heuristic
clusterers.

The same regressed centres for every clusterer: each log is labelled once with ``--scans 1``
(the ``infer`` stage runs once), then the ``shift`` stage onward is recomputed for each clusterer
setting (the run store's fingerprints decide). Heuristic parameters (and dynamic shifting's one
non-learned parameter, the final mean-shift bandwidth of the converged seeds) are grid-searched on a tuning
log (e.g. the validation log), the best setting of each family is scored on a held-out log:
PQ^Th, PQ, the shift stage's seconds per frame (official SemanticKITTI metrics).

    .venv/bin/python bench/ablation_clustering.py model --checkpoint CKPT --tune-data VAL
        --data HELDOUT --out DIR
"""


def _parser(mode: str, doc: str) -> argparse.ArgumentParser:
    return argparse.ArgumentParser(
        prog=f"ablation_clustering.py {mode}",
        description=doc,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )


# -- oracle ----------------------------------------------------------------------------------------
GRIDS = {
    "dynamic shift, fixed weights": [
        (lambda w: DynamicShiftClusterer(DynamicShift.with_fixed_weights(w)), w)
        for w in [(1, 0, 0), (0, 1, 0), (0, 0, 1), (0.3, 0.7, 0), (0.5, 0.5, 0), (1, 1, 1)]
    ],
    "mean shift (bin seeding)": [(MeanShiftClusterer, b) for b in (0.4, 0.65, 0.9, 1.2, 1.6, 2.0)],
    "DBSCAN": [(lambda p: DBSCANClusterer(*p), p) for p in itertools.product((0.2, 0.35, 0.5, 0.8), (5, 15))],
    "HDBSCAN": [(HDBSCANClusterer, m) for m in (10, 30, 80)],
    "BFS (radius components)": [
        (lambda p: BFSClusterer(*p), p) for p in itertools.product((0.1, 0.2, 0.3, 0.5), (5, 30))
    ],
}


def oracle_main(argv: list[str]) -> None:
    ap = _parser("oracle", ORACLE_DOC)
    ap.add_argument("--data", default="/tmp/dsnet_shift_bench", help="where the synthetic logs are cached")
    ap.add_argument("--frames", type=int, default=8, help="frames per sequence")
    ap.add_argument("--tune-scans", type=int, default=6)
    ap.add_argument("--steps", type=int, default=300)
    ap.add_argument("--noise-scale", type=float, default=1.0)
    ap.add_argument("--save-weights", default=None)
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    torch.manual_seed(0)
    t0 = time.perf_counter()
    data = Path(args.data)
    train = synth_scans(data / "train_seed1_vlp32", 1, 2, args.frames, args.noise_scale, "vlp32")
    tune = train[:: max(1, len(train) // args.tune_scans)][: args.tune_scans]
    train += synth_scans(data / "train_seed1", 1, 3, args.frames, args.noise_scale, "hdl64")[: args.frames]
    test = synth_scans(data / "test_seed2_vlp32", 2, 2, args.frames, args.noise_scale, "vlp32")
    print(
        f"{len(train)} training scans, {len(test)} held-out scans ({time.perf_counter() - t0:.0f} s)",
        flush=True,
    )
    samples = [make_sample(s.xyz[s.thing], s.centres, s.features, s.gt_centres, 10_000) for s in train]
    module = DynamicShift()
    losses = train_shift(module, samples, args.steps, lr=3e-3)
    print(
        f"trained {args.steps} steps on {len(samples)} scans: loss {np.mean(losses[:10]):.3f} -> "
        f"{np.mean(losses[-10:]):.3f} ({time.perf_counter() - t0:.0f} s incl. data)"
    )
    if args.save_weights:
        from safetensors.torch import save_file

        save_file(module.state_dict(), args.save_weights)
        print(f"wrote {args.save_weights}")
    rows = [
        (
            "dynamic shift, learned weights (oracle features)",
            "trained",
            *score(test, DynamicShiftClusterer(module)),
        )
    ]
    rows.append(("  same, on the training scenes", "trained", *score(tune, DynamicShiftClusterer(module))))
    for name, grid in GRIDS.items():
        tuned = [(score(tune, make(p))[0], p) for make, p in grid]
        best_pq, best = max(tuned, key=lambda t: t[0])
        make = next(m for m, p in grid if p == best)
        rows.append((name, f"{best} (train PQTh {best_pq:.3f})", *score(test, make(best))))
    print(
        f"\nheld-out PQ^Th, {len(test)} scenes, noise scale {args.noise_scale} "
        f"({time.perf_counter() - t0:.0f} s total)\n"
    )
    names = [LABEL_MAP.class_names[c] for c in LABEL_MAP.things]
    print("| clusterer | parameters (tuned on train) | PQ^Th | " + " | ".join(names) + " |")
    print("|---" * (3 + len(names)) + "|")
    for name, params, pq, per in rows:
        cls = " | ".join(f"{per.get(n, float('nan')):.3f}" for n in names)
        print(f"| {name} | {params} | {pq:.3f} | {cls} |")


# -- model -----------------------------------------------------------------------------------------
MODEL_GRIDS: dict[str, list[dict]] = {
    "dynamic shift (learned)": [{"kind": "dynamic_shift"}],
    # the non-learned knob of dynamic shifting (the seeds' final mean shift, 0.65 m in the paper),
    # searched like the heuristics' parameters
    "dynamic shift, final bandwidth tuned": [
        {"kind": "dynamic_shift", "final_bandwidth": b} for b in (0.4, 0.65, 0.9, 1.2)
    ],
    "mean shift (bin seeding)": [{"kind": "meanshift", "bandwidth": b} for b in (0.65, 0.9, 1.2, 1.6)],
    "DBSCAN": [
        {"kind": "dbscan", "eps": e, "min_samples": m} for e in (0.2, 0.35, 0.5, 0.8) for m in (5, 15)
    ],
    "HDBSCAN": [{"kind": "hdbscan", "min_cluster_size": m} for m in (10, 30)],
    "BFS (radius components)": [{"kind": "bfs", "radius": r, "min_size": 5} for r in (0.1, 0.2, 0.3, 0.5)],
}


def label(data: Path, run: Path, ckpt: str, clusterer: dict) -> float:
    """Label every sequence of ``data`` into ``run`` with ``clusterer``; seconds per frame of shift."""
    seqs = SemanticKittiReader(data).sequences()
    stages = stage_configs(scans=1, checkpoint=ckpt, clusterer=json.dumps(clusterer))
    summary = run_label(LabelRequest(data=str(data), root=str(run), sequences=seqs, stages=stages))
    if any(r["action"] == "failed" for r in summary):
        raise SystemExit(f"label flow failed: {summary}")
    store = RunStore(str(run))
    manifests = [store.read_manifest(s, "shift") for s in seqs]
    return sum(m.timings.get("block_s", 0.0) for m in manifests) / max(1, sum(m.n_items for m in manifests))


def model_score(data: Path, run: Path) -> tuple[float, float]:
    """(PQ^Th, PQ) of the run's stitched labels against ``data``'s ground truth (official mode)."""
    reader = SemanticKittiReader(data)
    store = RunStore(str(run))
    ev = PanopticEvaluator(load_label_map("semantic-kitti"), keep_rows=False)
    for seq in reader.sequences():
        for frame, pred in zip(reader.frames(seq), stitched(store, seq), strict=True):
            ev.add(reader.labels(frame), pred, frame=frame.frame_id, sequence=seq)
    res = ev.result().panoptic
    return res.pq_things, res.pq


def model_main(argv: list[str]) -> None:
    ap = _parser("model", MODEL_DOC)
    ap.add_argument("--checkpoint", required=True)
    ap.add_argument("--tune-data", type=Path, required=True, help="log on which the grids are searched")
    ap.add_argument("--data", type=Path, required=True, help="held-out log the best settings are scored on")
    ap.add_argument("--out", type=Path, required=True, help="run stores and results.json")
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    with prefect_api():  # one temporary Prefect server for every label run
        results = ablation(args)
    (args.out / "results.json").write_text(json.dumps(results, indent=2) + "\n")
    print("| clusterer | setting | PQ^Th | PQ | shift ms/frame |\n|---|---|---|---|---|")
    for family, r in results.items():
        setting = {k: v for k, v in r["setting"].items() if k != "kind"}
        print(
            f"| {family} | {setting or '—'} | {r['pq_things']:.4f} | {r['pq']:.4f} | "
            f"{1000 * r['shift_s_per_frame']:.1f} |"
        )


def ablation(args: argparse.Namespace) -> dict[str, dict]:
    """Grid-search every family on the tuning log, score its best setting on the held-out log."""
    results = {}
    for family, grid in MODEL_GRIDS.items():
        t0 = time.perf_counter()
        tuned = []
        for cfg in grid:
            label(args.tune_data, args.out / "tune", args.checkpoint, cfg)
            tuned.append((model_score(args.tune_data, args.out / "tune")[0], cfg))
        best_tune, best = max(tuned, key=lambda t: t[0])
        s_per_frame = label(args.data, args.out / "heldout", args.checkpoint, best)
        pq_th, pq = model_score(args.data, args.out / "heldout")
        results[family] = {
            "setting": best,
            "tune_pq_things": best_tune,
            "pq_things": pq_th,
            "pq": pq,
            "shift_s_per_frame": s_per_frame,
            "grid": [{"setting": c, "tune_pq_things": p} for p, c in tuned],
        }
        print(
            f"{family:28s} PQ^Th {pq_th:.4f}  PQ {pq:.4f}  shift {1000 * s_per_frame:7.1f} ms/frame  "
            f"(tuned {best_tune:.4f} with {best}; {time.perf_counter() - t0:.0f} s)",
            flush=True,
        )
    return results


MODES = {"oracle": oracle_main, "model": model_main}


def main(argv: list[str]) -> None:
    if not argv or argv[0] not in MODES:
        sys.exit(f"usage: ablation_clustering.py {{{'|'.join(MODES)}}} [options] (MODE --help: its options)")
    MODES[argv[0]](argv[1:])


if __name__ == "__main__":
    main(sys.argv[1:])
