"""DS-Net clustering ablation on a trained model: learned dynamic shifting vs heuristic clusterers.

The same regressed centres for every clusterer: each log is labelled once with ``--scans 1``
(the ``infer`` stage runs once), then the ``shift`` stage onward is recomputed for each clusterer
setting (the run store's fingerprints decide). Heuristic parameters (and dynamic shifting's one
non-learned parameter, the final mean-shift bandwidth of the converged seeds) are grid-searched on a tuning
log (e.g. the validation log), the best setting of each family is scored on a held-out log:
PQ^Th, PQ, the shift stage's seconds per frame (official SemanticKITTI metrics).

    .venv/bin/python bench/ablation_model.py --checkpoint CKPT --tune-data VAL --data HELDOUT --out DIR
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _store4d import stitched

from dsnet_core.io.semantickitti import SemanticKittiReader
from dsnet_core.labels import load_label_map
from dsnet_core.metrics import PanopticEvaluator
from flows.commands.label import run_label
from flows.request import LabelRequest
from flows.server import prefect_api
from storage.run import RunStore
from tasks.methods import stage_configs

GRIDS: dict[str, list[dict]] = {
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


def score(data: Path, run: Path) -> tuple[float, float]:
    """(PQ^Th, PQ) of the run's stitched labels against ``data``'s ground truth (official mode)."""
    reader = SemanticKittiReader(data)
    store = RunStore(str(run))
    ev = PanopticEvaluator(load_label_map("semantic-kitti"), keep_rows=False)
    for seq in reader.sequences():
        for frame, pred in zip(reader.frames(seq), stitched(store, seq), strict=True):
            ev.add(reader.labels(frame), pred, frame=frame.frame_id, sequence=seq)
    res = ev.result().panoptic
    return res.pq_things, res.pq


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--checkpoint", required=True)
    ap.add_argument("--tune-data", type=Path, required=True, help="log on which the grids are searched")
    ap.add_argument("--data", type=Path, required=True, help="held-out log the best settings are scored on")
    ap.add_argument("--out", type=Path, required=True, help="run stores and results.json")
    args = ap.parse_args()
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
    for family, grid in GRIDS.items():
        t0 = time.perf_counter()
        tuned = []
        for cfg in grid:
            label(args.tune_data, args.out / "tune", args.checkpoint, cfg)
            tuned.append((score(args.tune_data, args.out / "tune")[0], cfg))
        best_tune, best = max(tuned, key=lambda t: t[0])
        s_per_frame = label(args.data, args.out / "heldout", args.checkpoint, best)
        pq_th, pq = score(args.data, args.out / "heldout")
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


if __name__ == "__main__":
    main()
