"""Time per stage of the label pipeline on 64-beam (hdl64) synthetic frames, one torch thread.

Runs ingest → align → infer → shift → fuse → track (k = 1) or stitch (k > 1), the temporal
stage ``dsnet label`` picks by default (``--temporal`` forces one), then ``refine`` where the
tree's default pipeline has it (``--no-refine`` leaves it out), through the plain runner (no
Prefect) for each k, and prints seconds per frame for every stage (process CPU time, the steadier
number on a shared machine, and wall time), the peak RSS, and the temporal stage's share of a
frame's time (it should be a small fraction). Every stage's time includes its start (imports,
loading the model): use enough frames (24) to amortise it. Each (tree, k) runs in its own process
after a warm-up on a 2-frame log (numba's compiled-function caches, first-call costs).

``--baseline REV`` (repeatable) measures the same log in a git worktree of revision ``REV`` in the
same run and prints the ratios now / baseline (absolute times are not comparable across runs); a
stage a tree does not have counts 0. ``--profile DIR`` writes one cProfile file per (tree, k,
stage) of the measured log (``DIR/<tree>-k<k>-<stage>.prof``; the profiler's overhead inflates
the times printed).

Without ``--checkpoint`` it builds a RANDOM-WEIGHT ``tiny`` checkpoint: the network's cost is
the real one, but shifting then runs on whatever the random heads call "thing" (often far
more points than a trained model would), so shift time is a pessimistic bound.

Run: ``.venv/bin/python bench/bench_stages.py --frames 24 --scans 1 [--checkpoint PATH]
[--baseline REV ...] [--profile DIR]``
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
STAGES = ("ingest", "align", "infer", "shift", "fuse")  # then the temporal stage, then refine


def random_tiny_checkpoint(path: Path) -> Path:
    import torch

    from dsnet_core.labels import class_map_of, load_label_map
    from dsnet_core.model.checkpoint import ModelCard, save_checkpoint
    from dsnet_core.model.network import DSNet
    from dsnet_core.model.presets import get_preset

    torch.manual_seed(0)
    card = ModelCard(architecture={}, class_map=class_map_of(load_label_map("semantic-kitti")))
    return save_checkpoint(path, DSNet(get_preset("tiny")), card)


def label(log: Path, out: Path, ckpt: Path, k: int, temporal: str, refine: bool, profile: str = "") -> dict:
    """Run the label stages on ``log`` into a fresh store; seconds per stage (cpu and wall).

    ``profile``: a path prefix; each stage's cProfile goes to ``<profile>-<stage>.prof``."""
    from storage.run import RunStore
    from tasks.methods import get_pipeline
    from tasks.runner import run_stage_plain

    pipeline = get_pipeline("dsnet", temporal=temporal)
    has_refine = "refine" in [s.name for s in pipeline.stages]
    if has_refine and not refine:
        pipeline = get_pipeline("dsnet", temporal=temporal, refine=False)
    store = RunStore(out)
    run = {"data": str(log), "stages": {"align": {"scans": k}, "infer": {"checkpoint": str(ckpt)}}}
    store.write_run_config("bench", run)
    res: dict = {"cpu": {}, "wall": {}}
    for stage in (*STAGES, temporal, *(("refine",) if has_refine and refine else ())):
        prof = None
        if profile:
            import cProfile

            prof = cProfile.Profile()
            prof.enable()
        t0, c0 = time.perf_counter(), time.process_time()
        m = run_stage_plain(store, pipeline, "00", stage, run, "bench")
        res["wall"][stage], res["cpu"][stage] = time.perf_counter() - t0, time.process_time() - c0
        if prof is not None:
            prof.disable()
            prof.dump_stats(f"{profile}-{stage}.prof")
        if stage == "align":
            res["frames"] = store.read_manifest("00", "ingest").n_items
            res["points"] = m.counts["points"] / max(m.n_items, 1)
    infer = store.read_manifest("00", "infer")
    res["thing"] = infer.counts.get("thing_points", 0) / max(infer.n_items, 1)
    return res


def worker(
    root: Path, log: Path, warm_log: Path, ckpt: Path, k: int, temporal: str, refine: bool, profile: str
) -> dict:
    """One (tree, k) measurement in this process: a warm-up on ``warm_log``, then ``log``."""
    sys.path.insert(0, str(root))
    import torch

    torch.set_num_threads(1)
    with tempfile.TemporaryDirectory(prefix="bench-stages-run-") as tmp:
        label(warm_log, Path(tmp) / "warm", ckpt, k, temporal, refine)
        res = label(log, Path(tmp) / "run", ckpt, k, temporal, refine, profile)
    res["peak_mib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return res


def _table(name: str, res: dict, stages: tuple[str, ...], temporal: str) -> dict[str, float]:
    n = res["frames"]
    print(f"\n{name}: {n} frames, {res['points']:.0f} points per volume; seconds per frame:")
    per_frame = {}
    for clock in ("cpu", "wall"):
        pf = {s: res[clock].get(s, 0.0) / n for s in stages}
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
    ap.add_argument("--baseline", action="append", default=[], help="git revision to measure in the same run")
    ap.add_argument("--no-refine", action="store_true", help="leave refine out where the pipeline has it")
    ap.add_argument("--profile", type=Path, default=None, help="folder for one cProfile file per stage")
    ap.add_argument("--worker", nargs=8, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        root, log, warm, ckpt, k, temporal, refine, profile = args.worker
        res = worker(Path(root), Path(log), Path(warm), Path(ckpt), int(k), temporal, refine == "1", profile)
        print(json.dumps(res))
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
    git = ["git", "-C", str(ROOT), "worktree"]
    worktrees = []
    if args.profile:
        args.profile.mkdir(parents=True, exist_ok=True)
    try:
        for i, rev in enumerate(args.baseline):
            worktree = tmp / f"baseline-{i}"
            subprocess.run([*git, "add", "--detach", str(worktree), rev], check=True)
            worktrees.append(worktree)
            trees[f"baseline {rev}"] = worktree
        refine = "0" if args.no_refine else "1"
        for k in (int(s) for s in args.scans.split(",")):
            temporal = args.temporal if args.temporal != "auto" else ("track" if k == 1 else "stitch")
            stages = (*STAGES, temporal, *(() if args.no_refine else ("refine",)))
            cpu = {}
            for t, (name, root) in enumerate(trees.items()):
                tag = "now" if t == 0 else f"baseline{t}"
                prof = str(args.profile / f"{tag}-k{k}") if args.profile else ""
                cmd = [sys.executable, __file__, "--worker", str(root), str(log), str(warm), str(ckpt)]
                done = subprocess.run(
                    [*cmd, str(k), temporal, refine, prof], capture_output=True, text=True, cwd=root
                )
                if done.returncode:
                    sys.exit(f"{name} failed:\n{done.stderr[-3000:]}")
                res = json.loads(done.stdout.strip().splitlines()[-1])
                cpu[name] = _table(f"{name}, k = {k}", res, stages, temporal)
            now = cpu["now"]
            for name, then in list(cpu.items())[1:]:
                cells = "  ".join(
                    f"{s} {now[s] / then[s]:.2f}x" if then[s] else f"{s} -" for s in (*stages, "total")
                )
                print(f"\n  k = {k}, cpu now / {name}: {cells}")
    finally:
        for worktree in worktrees:
            subprocess.run([*git, "remove", "--force", str(worktree)], check=False)
    print(f"\nlogs under {tmp}")


if __name__ == "__main__":
    main()
