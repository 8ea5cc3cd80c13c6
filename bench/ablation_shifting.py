"""DS-Net clustering ablation on oracle inputs: learned dynamic shifting vs heuristic clusterers.

Oracle-feature experiment, no network: synthetic HDL-64 logs (``dsnet_core.synth``), ground-truth
semantics, ground-truth box centres plus the regression-noise model of ``dsnet_core.oracle.inputs``, and
32-d oracle features (ground-truth class one-hot + regressed-centre geometry) in place of the
backbone feature. The shifting MLPs are trained on logs of one seed (VLP-32 and HDL-64 scans);
every heuristic's parameters are tuned by grid search on a subset of the VLP-32 training scans;
all are scored (PQ^Th, official SemanticKITTI semantics, project evaluator) on a VLP-32 log of
another seed.

    .venv/bin/python bench/ablation_shifting.py [--save-weights PATH] [--data DIR]
"""

from __future__ import annotations

import argparse
import itertools
import time
from pathlib import Path

import numpy as np
import torch
from _oracle import LABEL_MAP, score, synth_scans

from dsnet_core.instance.clustering import (
    BFSClusterer,
    DBSCANClusterer,
    DynamicShiftClusterer,
    HDBSCANClusterer,
    MeanShiftClusterer,
)
from dsnet_core.instance.shifting import DynamicShift
from dsnet_core.train.shifting import make_sample, train_shift

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


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", default="/tmp/dsnet_shift_bench", help="where the synthetic logs are cached")
    ap.add_argument("--frames", type=int, default=8, help="frames per sequence")
    ap.add_argument("--tune-scans", type=int, default=6)
    ap.add_argument("--steps", type=int, default=300)
    ap.add_argument("--noise-scale", type=float, default=1.0)
    ap.add_argument("--save-weights", default=None)
    args = ap.parse_args()
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


if __name__ == "__main__":
    main()
