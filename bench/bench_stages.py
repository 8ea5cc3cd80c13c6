"""Time per stage of the label pipeline on 64-beam (hdl64) synthetic frames with the ``tiny`` model.

Runs ingest → align → infer → shift → fuse → track (k = 1) or stitch (k > 1), the temporal
stage ``dsnet label`` picks by default (``--temporal`` forces one), through the plain runner
(no Prefect, one torch thread) for each k, and prints seconds per frame for every stage (wall
and process CPU time: on a shared machine the CPU time is the steadier number), the peak RSS,
and the temporal stage's share of a frame's time (it should be a small fraction). Every stage's
time includes its start (imports, loading the model): use enough frames (24) to amortise it.

Without ``--checkpoint`` it builds a RANDOM-WEIGHT ``tiny`` checkpoint: the network's cost is
the real one, but shifting then runs on whatever the random heads call "thing" (often far
more points than a trained model would), so shift time is a pessimistic bound.

Run: ``.venv/bin/python bench/bench_stages.py [--frames 5] [--scans 1,2,3,4] [--checkpoint PATH]``
(each k in its own process for its own peak RSS).
"""

from __future__ import annotations

import argparse
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import torch

from tasks.methods import get_pipeline

STAGES = ("ingest", "align", "infer", "shift", "fuse")  # then the temporal stage


def random_tiny_checkpoint(path: Path) -> Path:
    from dsnet_core.labels import class_map_of, load_label_map
    from dsnet_core.model.checkpoint import ModelCard, save_checkpoint
    from dsnet_core.model.network import DSNet
    from dsnet_core.model.presets import get_preset

    torch.manual_seed(0)
    card = ModelCard(architecture={}, class_map=class_map_of(load_label_map("semantic-kitti")))
    return save_checkpoint(path, DSNet(get_preset("tiny")), card)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=5)
    ap.add_argument("--scans", default="1,2,3,4")
    ap.add_argument("--checkpoint", type=Path, default=None)
    ap.add_argument("--log", type=Path, default=None, help="existing hdl64 log (default: generate one)")
    ap.add_argument("--temporal", choices=("auto", "track", "stitch"), default="auto")
    args = ap.parse_args()
    torch.set_num_threads(1)

    from dsnet_core.synth import generate_log
    from storage.run import RunStore
    from tasks.runner import run_stage_plain

    tmp = Path(tempfile.mkdtemp(prefix="bench-stages-"))
    log = args.log
    if log is None:
        log = tmp / "log"
        t0 = time.perf_counter()
        generate_log(log, sequences=1, frames=args.frames, seed=0, sensor="hdl64")
        print(f"generated {args.frames} hdl64 frames in {time.perf_counter() - t0:.1f} s ({log})")
    ckpt = args.checkpoint or random_tiny_checkpoint(tmp / "tiny-random")
    ks = [int(s) for s in args.scans.split(",")]
    if len(ks) > 1:  # one process per k, so that each k gets its own peak RSS
        print(f"checkpoint: {ckpt}{'' if args.checkpoint else ' (random weights, tiny preset)'}")
        for k in ks:
            cmd = [sys.executable, __file__, "--scans", str(k), "--log", str(log), "--checkpoint", str(ckpt)]
            cmd += ["--temporal", args.temporal]
            subprocess.run(cmd, check=True)
        return
    for k in ks:
        temporal = args.temporal if args.temporal != "auto" else ("track" if k == 1 else "stitch")
        P = get_pipeline("dsnet", temporal=temporal)
        stages = (*STAGES, temporal)
        store = RunStore(tmp / f"run-k{k}")
        run = {"data": str(log), "stages": {"align": {"scans": k}, "infer": {"checkpoint": str(ckpt)}}}
        store.write_run_config("bench", run)
        times, cpu = {}, {}
        for stage in stages:
            t0, c0 = time.perf_counter(), time.process_time()
            m = run_stage_plain(store, P, "00", stage, run, "bench")
            times[stage], cpu[stage] = time.perf_counter() - t0, time.process_time() - c0
            if stage == "align":
                n_frames = store.read_manifest("00", "ingest").n_items
                points = m.counts["points"] / max(m.n_items, 1)
        print(f"\nk = {k}: {n_frames} frames, {points:.0f} points per volume; seconds per frame:")
        for name, t in (("wall", times), ("cpu", cpu)):
            per_frame = {s: v / n_frames for s, v in t.items()}
            total = sum(per_frame.values())
            cells = "  ".join(f"{s} {per_frame[s]:.3f}" for s in stages)
            share = 100 * per_frame[temporal] / total
            print(f"  {name:>4}: {cells}  | total {total:.2f}  ({temporal} {share:.1f}%)")
        thing = store.read_manifest("00", "infer").counts.get("thing_points", 0)
        print(f"  thing points per volume (as the model labels them): {thing / max(m.n_items, 1):.0f}")
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"  peak RSS {peak:.0f} MiB (this k); stores under {tmp}")


if __name__ == "__main__":
    main()
