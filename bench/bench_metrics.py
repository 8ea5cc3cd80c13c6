"""Scoring speed and memory, against the public evaluators measured in the same run.

1. ~120k points per frame: our PQ + mIoU + LSTQ (one ``PanopticEvaluator.add``) vs the public
   ``PanopticEval`` (semantic-kitti-api) computing PQ + mIoU alone, driven as
   ``evaluate_panoptic.py`` drives it; and our LSTQ alone vs a literal re-implementation of
   4D-PLS's per-class loop (``Ref4DPLS``; 4D-PLS itself is not installable).
2. Peak memory of scoring one long sequence (default 4 000 frames) with ``tracemalloc``,
   printed at checkpoints to show it stays flat.

Run: ``.venv/bin/python bench/bench_metrics.py [--frames 30] [--points 120000] [--long 4000]``.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import resource
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from dsnet_core.labels import load_label_map
from dsnet_core.metrics.decode import ClassSpec, KittiDecoder, make_cells
from dsnet_core.metrics.evaluator import PanopticEvaluator
from dsnet_core.metrics.lstq import LSTQAccumulator
from tests.dsnet_core.metrics.ref_4dpls import Ref4DPLS

STUFF_RAW = [40, 44, 48, 49, 50, 51, 70, 71, 72, 80, 81, 60]
THING_RAW = [10, 11, 13, 15, 18, 20, 30, 31, 32, 252]


def make_frame(rng: np.random.Generator, n: int, t: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A SemanticKITTI-like frame: 12 stuff regions, ~30 thing instances, ~3% unlabeled.

    Instance ids drift with ``t`` (new objects enter every 50 frames). Predictions relabel 8% of
    points, split one instance in three and merge pairs of instances.
    """
    sizes = np.concatenate([rng.integers(3000, 15000, len(STUFF_RAW)), rng.integers(80, 2500, 30)])
    sizes = np.round(sizes / sizes.sum() * n * 0.97).astype(np.int64)
    sem = np.concatenate([STUFF_RAW, rng.choice(THING_RAW, 30)]).astype(np.uint32)
    inst = np.concatenate([np.zeros(len(STUFF_RAW)), 1 + t // 50 + np.arange(30)]).astype(np.uint32)
    seg = np.repeat(np.arange(sizes.size), sizes)
    seg = np.concatenate([seg, np.full(n - seg.size, -1)])
    gt = np.where(seg >= 0, sem[seg] | (inst[seg] << 16), 0).astype(np.uint32)
    gt = gt[rng.permutation(n)]
    pred = gt.copy()
    flip = rng.random(n) < 0.08
    pred[flip] = rng.choice(STUFF_RAW + THING_RAW, int(flip.sum())).astype(np.uint32)
    ids = pred >> 16
    for k in range(1, 30, 4):  # merge instance k+1 into k
        pred[ids == k + 1 + t // 50] = pred[ids == k + t // 50][:1] if (ids == k + t // 50).any() else 0
    split = np.flatnonzero(ids == 3 + t // 50)
    pred[split[::3]] = (pred[split[::3]] & 0xFFFF) | (900 << 16)
    return gt, pred


def timed(fn, reps: int = 1) -> float:
    best = float("inf")
    for _ in range(reps):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def bench_speed(frames: list[tuple[np.ndarray, np.ndarray]]) -> None:
    lm = load_label_map("semantic-kitti")
    maxkey = max(lm.learning_map)
    lut = np.zeros(maxkey + 100, dtype=np.int32)
    lut[list(lm.learning_map)] = list(lm.learning_map.values())
    nf = len(frames)

    def ours_all() -> None:
        ev = PanopticEvaluator(lm, keep_rows=False)
        for k, (gt, pred) in enumerate(frames):
            ev.add(gt, pred, frame=str(k), sequence="08")
        ev.result()

    def ours_lstq() -> None:
        dec = KittiDecoder(lm)
        acc = LSTQAccumulator(ClassSpec.from_label_map(lm), 50)
        for gt, pred in frames:
            acc.add(make_cells(gt, pred, dec, dec), "08")
        acc.result()

    def ref_lstq() -> None:
        ref = Ref4DPLS(min_points=50)
        for gt, pred in frames:
            ref.add("08", lut[pred & 0xFFFF], pred >> 16, lut[gt & 0xFFFF], gt >> 16)
        ref.get()

    ev = PanopticEvaluator(lm, keep_rows=False)
    for k, (gt, pred) in enumerate(frames):
        ev.add(gt, pred, frame=str(k), sequence="08")
    ours = ev.result()
    t_ours = timed(ours_all, 3)
    t_ours_lstq = timed(ours_lstq, 3)
    t_ref_lstq = timed(ref_lstq)
    print(f"frames: {nf} x {frames[0][0].size} points")
    print(f"ours  PQ+mIoU+LSTQ      {1e3 * t_ours / nf:8.2f} ms/frame")
    print(f"ours  LSTQ only         {1e3 * t_ours_lstq / nf:8.2f} ms/frame")
    print(
        f"4D-PLS loop (re-impl.)  {1e3 * t_ref_lstq / nf:8.2f} ms/frame   "
        f"ratio ours/ref = {t_ours_lstq / t_ref_lstq:.3f}"
    )
    try:
        with contextlib.redirect_stdout(io.StringIO()):
            from auxiliary.eval_np import PanopticEval
    except ImportError:
        print("public PanopticEval: not installed (pip install --no-deps semantic-kitti-api==0.1)")
        return

    def ref_pq() -> None:
        with contextlib.redirect_stdout(io.StringIO()):
            ref = PanopticEval(20, None, [0], min_points=50)
        for gt, pred in frames:
            ref.addBatch(lut[pred & 0xFFFF], pred, lut[gt & 0xFFFF], gt)
        ref.getPQ(), ref.getSemIoU()

    t_ref = timed(ref_pq)
    with contextlib.redirect_stdout(io.StringIO()):
        ref = PanopticEval(20, None, [0], min_points=50)
    for gt, pred in frames:
        ref.addBatch(lut[pred & 0xFFFF], pred, lut[gt & 0xFFFF], gt)
    diff = max(abs(ours.panoptic.pq - ref.getPQ()[0]), abs(ours.panoptic.miou - ref.getSemIoU()[0]))
    print(
        f"agreement: PQ {ours.panoptic.pq:.6f}, mIoU {ours.panoptic.miou:.6f}, max |ours - ref| = {diff:.1e}"
    )
    print(f"PanopticEval PQ+mIoU    {1e3 * t_ref / nf:8.2f} ms/frame")
    print(f"ratio (ours PQ+mIoU+LSTQ) / (PanopticEval PQ+mIoU) = {t_ours / t_ref:.3f}  (goal ≤ 0.5)")


def bench_memory(n_frames: int, n_points: int) -> None:
    lm = load_label_map("semantic-kitti")
    rng = np.random.default_rng(1)
    pool = [make_frame(rng, n_points, t) for t in range(0, 200, 10)]
    ev = PanopticEvaluator(lm, keep_rows=False)
    tracemalloc.start()
    checkpoints = {n_frames // 8, n_frames // 4, n_frames // 2, n_frames}
    t0 = time.perf_counter()
    for t in range(1, n_frames + 1):
        gt, pred = pool[t % len(pool)]
        shift = np.uint32((t // 50) << 16)  # new instance ids every 50 frames: tubes keep growing
        gt_t = np.where(gt >> 16 > 0, gt + shift, gt)
        pred_t = np.where(pred >> 16 > 0, pred + shift, pred)
        ev.add(gt_t, pred_t, frame=f"{t:06d}", sequence="00")
        if t in checkpoints:
            cur, peak = tracemalloc.get_traced_memory()
            tubes = len(ev.lstq.seqs["00"].tubes)
            inter = len(ev.lstq.seqs["00"].inter)
            print(
                f"after {t:5d} frames: traced now {cur / 2**20:6.2f} MiB, peak {peak / 2**20:6.2f} MiB "
                f"(tubes {tubes}, intersections {inter})"
            )
    r = ev.result()
    tracemalloc.stop()
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(
        f"{n_frames} frames x {n_points} points in {time.perf_counter() - t0:.1f} s; LSTQ {r.lstq.lstq:.4f}"
    )
    print(f"process peak RSS (whole run, incl. interpreter and the 120k-point frames): {rss:.0f} MiB")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--points", type=int, default=120_000)
    ap.add_argument("--long", type=int, default=4000, help="frames of the memory run (0 to skip)")
    ap.add_argument("--long-points", type=int, default=20_000)
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    frames = [make_frame(rng, args.points, t) for t in range(args.frames)]
    bench_speed(frames)
    if args.long:
        bench_memory(args.long, args.long_points)


if __name__ == "__main__":
    main()
