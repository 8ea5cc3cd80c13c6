"""Time per stage of the label pipeline on 64-beam (hdl64) synthetic frames, one torch thread.

Runs ingest → align → infer → shift → fuse → track (k = 1) or stitch (k > 1), the temporal
stage ``dsnet label`` picks by default (``--temporal`` forces one), then ``refine`` where the
tree's pipeline has it (on by default since refine was added), through the plain runner
(no Prefect) for each k, and prints seconds per frame for every stage (process CPU time, the
steadier number on a shared machine, and wall time), the peak RSS, and the temporal stage's share
of a frame's time (it should be a small fraction). Every stage's time includes its start (imports,
loading the model): use enough frames (24) to amortise it. Each (tree, k) runs in its own process
after a warm-up on a 2-frame log (numba's compiled-function caches, first-call costs).

``--baseline REV`` measures the same log in a git worktree of revision ``REV`` in the same run and
prints the ratios now / baseline (absolute times are not comparable across runs).

Without ``--checkpoint`` it builds a RANDOM-WEIGHT ``tiny`` checkpoint: the network's cost is
the real one, but shifting then runs on whatever the random heads call "thing" (often far
more points than a trained model would), so shift time is a pessimistic bound.

Run: ``.venv/bin/python bench/bench_stages.py --frames 24 --scans 1 [--checkpoint PATH]
[--baseline REV]``
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
STAGES = ("ingest", "align", "infer", "shift", "fuse")  # then the temporal stage


def random_tiny_checkpoint(path: Path) -> Path:
    import torch

    from dsnet_core.labels import class_map_of, load_label_map
    from dsnet_core.model.checkpoint import ModelCard, save_checkpoint
    from dsnet_core.model.network import DSNet
    from dsnet_core.model.presets import get_preset

    torch.manual_seed(0)
    card = ModelCard(architecture={}, class_map=class_map_of(load_label_map("semantic-kitti")))
    return save_checkpoint(path, DSNet(get_preset("tiny")), card)


def label(log: Path, out: Path, ckpt: Path, k: int, temporal: str) -> dict:
    """Run the label stages on ``log`` into a fresh store; seconds per stage (cpu and wall)."""
    from storage.run import RunStore
    from tasks.methods import get_pipeline
    from tasks.runner import run_stage_plain

    pipeline = get_pipeline("dsnet", temporal=temporal)
    store = RunStore(out)
    run = {"data": str(log), "stages": {"align": {"scans": k}, "infer": {"checkpoint": str(ckpt)}}}
    store.write_run_config("bench", run)
    res: dict = {"cpu": {}, "wall": {}}
    res["stages"] = [s for s in pipeline.names() if s != "score"]
    for stage in res["stages"]:
        t0, c0 = time.perf_counter(), time.process_time()
        m = run_stage_plain(store, pipeline, "00", stage, run, "bench")
        res["wall"][stage], res["cpu"][stage] = time.perf_counter() - t0, time.process_time() - c0
        if stage == "align":
            res["frames"] = store.read_manifest("00", "ingest").n_items
            res["points"] = m.counts["points"] / max(m.n_items, 1)
    thing = store.read_manifest("00", "infer").counts.get("thing_points", 0)
    res["thing"] = thing / max(m.n_items, 1)
    return res


def worker(root: Path, log: Path, warm_log: Path, ckpt: Path, k: int, temporal: str) -> dict:
    """One (tree, k) measurement in this process: a warm-up on ``warm_log``, then ``log``."""
    sys.path.insert(0, str(root))
    import torch

    torch.set_num_threads(1)
    with tempfile.TemporaryDirectory(prefix="bench-stages-run-") as tmp:
        label(warm_log, Path(tmp) / "warm", ckpt, k, temporal)
        res = label(log, Path(tmp) / "run", ckpt, k, temporal)
    res["peak_mib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return res


def _table(name: str, res: dict, stages: tuple[str, ...], temporal: str) -> dict[str, float]:
    n = res["frames"]
    print(f"\n{name}: {n} frames, {res['points']:.0f} points per volume; seconds per frame:")
    per_frame = {}
    for clock in ("cpu", "wall"):
        pf = {s: res[clock][s] / n for s in stages}
        total = sum(pf.values())
        cells = "  ".join(f"{s} {pf[s]:.3f}" for s in stages)
        print(f"  {clock:>4}: {cells}  | total {total:.2f}  ({temporal} {100 * pf[temporal] / total:.1f}%)")
        per_frame[clock] = {**pf, "total": total}
    print(f"  thing points per volume: {res['thing']:.0f}; peak RSS {res['peak_mib']:.0f} MiB")
    return per_frame["cpu"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=24)
    ap.add_argument("--scans", default="1,2,3,4")
    ap.add_argument("--checkpoint", type=Path, default=None)
    ap.add_argument("--log", type=Path, default=None, help="existing hdl64 log (default: generate one)")
    ap.add_argument("--temporal", choices=("auto", "track", "stitch"), default="auto")
    ap.add_argument("--baseline", default=None, help="git revision to measure in the same run")
    ap.add_argument("--worker", nargs=6, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        root, log, warm, ckpt, k, temporal = args.worker
        print(json.dumps(worker(Path(root), Path(log), Path(warm), Path(ckpt), int(k), temporal)))
        return

    sys.path.insert(0, str(ROOT))
    from dsnet_core.synth import generate_log

    tmp = Path(tempfile.mkdtemp(prefix="bench-stages-"))
    log = args.log
    if log is None:
        log = tmp / "log"
        t0 = time.perf_counter()
        generate_log(log, sequences=1, frames=args.frames, seed=0, sensor="hdl64")
        print(f"generated {args.frames} hdl64 frames in {time.perf_counter() - t0:.1f} s ({log})")
    warm = tmp / "warm-log"
    generate_log(warm, sequences=1, frames=2, seed=1, sensor="hdl64")
    ckpt = args.checkpoint or random_tiny_checkpoint(tmp / "tiny-random")
    print(f"checkpoint: {ckpt}{'' if args.checkpoint else ' (random weights, tiny preset)'}")
    trees = {"now": ROOT}
    if args.baseline:
        worktree = tmp / "baseline"
        git = ["git", "-C", str(ROOT), "worktree"]
        subprocess.run([*git, "add", "--detach", str(worktree), args.baseline], check=True)
        trees[f"baseline {args.baseline}"] = worktree
    try:
        for k in (int(s) for s in args.scans.split(",")):
            temporal = args.temporal if args.temporal != "auto" else ("track" if k == 1 else "stitch")
            cpu = {}
            for name, root in trees.items():
                cmd = [sys.executable, __file__, "--worker", str(root), str(log), str(warm), str(ckpt)]
                done = subprocess.run([*cmd, str(k), temporal], capture_output=True, text=True, cwd=root)
                if done.returncode:
                    sys.exit(f"{name} failed:\n{done.stderr[-3000:]}")
                res = json.loads(done.stdout.strip().splitlines()[-1])
                cpu[name] = _table(f"{name}, k = {k}", res, tuple(res["stages"]), temporal)
            if len(cpu) == 2:
                now, then = cpu.values()
                common = [s for s in now if s in then]
                cells = "  ".join(f"{s} {now[s] / then[s]:.2f}x" for s in common)
                print(f"\n  k = {k}, cpu now / baseline: {cells}")
    finally:
        if args.baseline:
            subprocess.run([*git, "remove", "--force", str(worktree)], check=False)
    print(f"\nlogs under {tmp}")


if __name__ == "__main__":
    main()
