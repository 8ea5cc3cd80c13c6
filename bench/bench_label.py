"""How long labelling takes, one script with four modes (``bench/bench_label.py MODE [options]``):

    stages    seconds per stage per frame through the plain runner, per k, against git revisions
    overhead  orchestration and store overhead: the stage work alone, the plain runner, the flow
    scale     how ``dsnet label`` / status / export / dashboard grow with the sequence length
    dask      ``dsnet label`` on a Dask cluster, 1 vs 2 workers, next to the thread runner

Without a mode it runs each mode in turn with its defaults, each in its own process (what
``make bench`` runs). ``bench/bench_label.py MODE --help`` prints that mode's description and
options (kept below as ``STAGES_DOC`` … ``DASK_DOC``).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

STAGES_DOC = """Time per stage of the label pipeline on 64-beam (hdl64) synthetic frames, one torch thread.

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

Run: ``.venv/bin/python bench/bench_label.py stages --frames 24 --scans 1 [--checkpoint PATH]
[--baseline REV ...] [--profile DIR]``
"""

OVERHEAD_DOC = """Orchestration + store overhead of ``label_sequence`` vs the same stage functions in a
plain loop.

Runs on a synthetic 100-frame sequence (tests/logs.py's parked-car street, ~120k points a frame):
    compute   the stage's core work with no store: read + check every scan, checksum, build volumes;
    plain     the stage runner in a plain loop (prepare, every block, finalise: all store writes,
              no Prefect, no locks);
    flow      ``label_sequence`` on a running Prefect server (server start-up excluded, reported),
              with one worker thread (same parallelism as the loop) and with the default pool;
    no-op     the rerun of the finished sequence: the store work (skip decisions), and the whole flow.

    .venv/bin/python bench/bench_label.py overhead [--frames 100] [--points 120000] [--scans 2]
"""

SCALE_DOC = """How labelling grows with the length of a sequence: one generated sequence per length, labelled
with ``dsnet label`` (the product's defaults: bundled model, k = 2, stitched, scored), then
``dsnet status``, ``dsnet export`` and ``dsnet dashboard`` on the run.

Per length it reports seconds per frame (the ``label`` command's wall and CPU time, each stage's
wall time from its manifest, and the median over its blocks of seconds per item: the figure the
load of a shared machine moves least), the label process's peak RSS, the store's bytes per frame
(and per stage), and the wall time and peak RSS of the three commands; then, against the shortest
length, the ratios of every per-frame figure (1.0 = grows like the frame count; the aims: peak
RSS ≤ 1.2×, seconds per frame within ±10 %, each command ≤ 2 s at 1,000 frames).

Every command is a fresh process (``python -m flows.cli``), so its Python start and imports
(~1 s on a loaded 2-core machine) are inside its time. The sensor defaults to ``vlp32`` (32 beams,
~25 k points per frame: a far lighter load than the 124 k-point hdl64 of the speed benches; the
growth with length is the question here). Stages run blocks of 25 items in parallel threads, so
lengths under 50 frames are no baseline. Logs are generated once into ``--work`` and reused.

Run: ``nice -n 19 .venv/bin/python bench/bench_label.py scale --lengths 100,300,1000 [--sensor vlp32]
[--work DIR] [--json FILE]``.
"""

DASK_DOC = """Throughput of ``dsnet label`` on a real Dask cluster: 1 vs 2 workers, next to the default
thread runner, in the same run.

Generates a synthetic log (``--sequences`` × ``--frames``, hdl64), builds a seeded random-weight
``tiny`` checkpoint, starts ``dask scheduler`` + N single-threaded ``dask worker`` processes on
loopback (tests/helpers/cluster.py: the same processes as the cluster tests) and runs
``dsnet label --dask-address`` into a fresh local run folder for N = 1 and N = 2, and once without
Dask (threads). Prints wall seconds, frames per second and the ratios; the Prefect server is a
temporary one for the whole bench. Each worker uses one torch thread; on a 2-core machine the
2-worker figure is bounded by the cores left to the scheduler, the flow process and the server.

Run: ``.venv/bin/python bench/bench_label.py dask [--sequences 4] [--frames 6] [--scans 2]``
"""


def _parser(mode: str, doc: str) -> argparse.ArgumentParser:
    return argparse.ArgumentParser(
        prog=f"bench_label.py {mode}", description=doc, formatter_class=argparse.RawDescriptionHelpFormatter
    )


# -- stages ------------------------------------------------------------------------------------
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


def stages_label(
    log: Path, out: Path, ckpt: Path, k: int, temporal: str, refine: bool, profile: str = ""
) -> dict:
    """Run the label stages on ``log`` into a fresh store; seconds per stage (cpu and wall).

    ``profile``: a path prefix; each stage's cProfile goes to ``<profile>-<stage>.prof``."""
    from storage.run import RunStore
    from tasks.methods import get_pipeline
    from tests.helpers.plain_runner import run_stage_plain

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
        stages_label(warm_log, Path(tmp) / "warm", ckpt, k, temporal, refine)
        res = stages_label(log, Path(tmp) / "run", ckpt, k, temporal, refine, profile)
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


def stages_main(argv: list[str]) -> None:
    ap = _parser("stages", STAGES_DOC)
    ap.add_argument("--frames", type=int, default=24)
    ap.add_argument("--scans", default="1,2,3,4")
    ap.add_argument("--checkpoint", type=Path, default=None)
    ap.add_argument("--log", type=Path, default=None, help="existing hdl64 log (default: generate one)")
    ap.add_argument("--temporal", choices=("auto", "track", "stitch"), default="auto")
    ap.add_argument("--baseline", action="append", default=[], help="git revision to measure in the same run")
    ap.add_argument("--no-refine", action="store_true", help="leave refine out where the pipeline has it")
    ap.add_argument("--profile", type=Path, default=None, help="folder for one cProfile file per stage")
    ap.add_argument("--worker", nargs=8, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
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
                cmd = [
                    sys.executable,
                    __file__,
                    "stages",
                    "--worker",
                    str(root),
                    str(log),
                    str(warm),
                    str(ckpt),
                ]
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


# -- overhead ----------------------------------------------------------------------------------
def compute_only(log: Path, scans: int) -> None:
    import numpy as np

    from dsnet_core.io.semantickitti import SemanticKittiReader
    from dsnet_core.temporal.align import build_volume, plan_windows
    from tasks.ingest import frame_checksum

    reader = SemanticKittiReader(log)
    refs = reader.frames("00")
    data = []
    for ref in refs:
        scan, labels = reader.scan(ref), reader.labels(ref)
        frame_checksum(scan, labels)
        data.append((scan, labels, reader.pose(ref)))
    cache = {}
    for w in plan_windows(len(refs), scans, max(scans - 1, 1)):
        for f in w:  # align re-reads its scans from the log, like the stage
            if f not in cache:
                scan, labels = reader.scan(refs[f]), reader.labels(refs[f])
                frame_checksum(scan, labels)
                cache[f] = (scan, labels)
        build_volume([cache[f][0] for f in w], [data[f][2] for f in w], list(w), [cache[f][1] for f in w])
        for f in [f for f in cache if f < w[-1]]:
            del cache[f]
    np.asarray(0)


def overhead_main(argv: list[str]) -> None:
    from flows.server import quiet_prefect_env
    from tasks.methods import get_pipeline
    from tests.helpers.label_request import req

    P = get_pipeline()  # the DS-Net stages
    quiet_prefect_env()
    ap = _parser("overhead", OVERHEAD_DOC)
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--points", type=int, default=120_000)
    ap.add_argument("--scans", type=int, default=2)
    ap.add_argument("--block-size", type=int, default=25)
    ap.add_argument("--rounds", type=int, default=2)
    args = ap.parse_args(argv)

    from tests.logs import make_log

    tmp = Path(tempfile.mkdtemp(prefix="dsnet-bench-"))
    os.environ.setdefault("PREFECT_HOME", str(tmp / "prefect-home"))
    log = make_log(tmp / "log", ("00",), n_frames=args.frames, n_ground=args.points - 300)
    stages = {"align": {"scans": args.scans}}
    options = {"block_size": args.block_size}
    print(
        f"log: {args.frames} frames x ~{args.points} points, scans={args.scans}, block_size={args.block_size}"
    )

    from flows.server import prefect_api
    from storage.run import RunStore
    from tests.helpers.plain_runner import prepare_stage, run_stage_plain

    t = time.perf_counter()
    with prefect_api() as _:
        t_server = time.perf_counter() - t
        from prefect.task_runners import ThreadPoolTaskRunner

        from flows.label import label_sequence

        label_sequence(
            req(str(log), str(tmp / "warm"), None, stages, options, until="align"), "00"
        )  # warm imports and the API
        times: dict[str, list[float]] = {}
        block_s: dict[str, list[float]] = {}
        for rnd in range(args.rounds):  # interleaved rounds: a loaded machine drifts; keep the best of each
            t = time.perf_counter()
            compute_only(log, args.scans)
            times.setdefault("compute only (no store)", []).append(time.perf_counter() - t)
            store = RunStore(tmp / f"plain-{rnd}")
            run = {"data": str(log), "stages": stages, "options": options}
            store.write_run_config("plain", run)
            t = time.perf_counter()
            ms = [run_stage_plain(store, P, "00", stage, run, "plain") for stage in ("ingest", "align")]
            times.setdefault("plain loop (stage runner)", []).append(time.perf_counter() - t)
            block_s.setdefault("plain loop (stage runner)", []).append(sum(m.timings["block_s"] for m in ms))
            for name, workers in (("flow, 1 worker thread", 1), ("flow, 4 worker threads", 4)):
                fl = label_sequence.with_options(task_runner=ThreadPoolTaskRunner(max_workers=workers))
                root = tmp / f"{workers}-{rnd}"
                t = time.perf_counter()
                summary = fl(req(str(log), str(root), None, stages, options, until="align"), "00")
                times.setdefault(name, []).append(time.perf_counter() - t)
                assert {r["action"] for r in summary} == {"fresh"}
                ms = [RunStore(root).read_manifest("00", s) for s in ("ingest", "align")]
                block_s.setdefault(name, []).append(sum(m.timings["block_s"] for m in ms))
        t = time.perf_counter()
        summary = label_sequence(req(str(log), str(root), None, stages, options, until="align"), "00")
        t_noop_flow = time.perf_counter() - t
        assert {r["action"] for r in summary} == {"skip"}
        t = time.perf_counter()
        for stage in ("ingest", "align"):
            assert prepare_stage(store, P, "00", stage, run, "plain").action == "skip"
        t_noop_store = time.perf_counter() - t

    best = {k: min(v) for k, v in times.items()}
    t_compute, t_plain = best["compute only (no store)"], best["plain loop (stage runner)"]
    for name, secs in best.items():
        line = f"{name:<30} {secs:8.2f} s (best of {len(times[name])})"
        if name in block_s:
            line += f"  in blocks {min(block_s[name]):6.2f} s"
        if name.startswith("flow"):
            line += f"  overhead vs plain loop {100 * (secs / t_plain - 1):+6.1f}%"
        if name != "compute only (no store)":
            line += f"  x{secs / t_compute:.3f} of compute only"
        print(line)
    print(f"no-op rerun, store work        {t_noop_store:8.3f} s")
    print(f"no-op rerun, whole flow        {t_noop_flow:8.3f} s")
    print(f"temporary Prefect server start {t_server:8.2f} s (once per CLI call without PREFECT_API_URL)")


# -- scale -------------------------------------------------------------------------------------
SEQ = "00"


def dsnet(args: list[str], log: Path) -> tuple[float, float, int, float]:
    """Run ``dsnet ARGS`` (output appended to ``log``): (wall seconds, peak RSS MiB, exit status,
    CPU seconds of the process, all its threads; its child processes not included)."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    with open(log, "a") as out:
        out.write(f"\n$ dsnet {' '.join(args)}\n")
        out.flush()
        t0 = time.perf_counter()
        proc = subprocess.Popen(
            [sys.executable, "-m", "flows.cli", *args], cwd=ROOT, env=env, stdout=out, stderr=out
        )
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - t0
    proc.returncode = os.waitstatus_to_exitcode(status)
    return wall, usage.ru_maxrss / 1024, proc.returncode, usage.ru_utime + usage.ru_stime


def stage_times(run: Path) -> dict[str, dict[str, float]]:
    """Per stage, from its manifest and block fragments: ``stages_s`` its wall time, ``blocks_s``
    the sum of its blocks' times (blocks of 25 items run in parallel threads: the sum is the work,
    inflated by contention), ``median_item_s`` the median over its blocks of seconds per item (the
    figure least moved by other load on a shared machine)."""
    out: dict[str, dict[str, float]] = {"stages_s": {}, "blocks_s": {}, "median_item_s": {}}
    for manifest in sorted((run / "sequences" / SEQ).glob("*/manifest.json")):
        m = json.loads(manifest.read_text())
        out["stages_s"][m["stage"]] = m["timings"].get("wall_s", float("nan"))
        out["blocks_s"][m["stage"]] = m["timings"].get("block_s", float("nan"))
        per_item = []
        for frag in manifest.parent.glob("blocks/*.json"):
            f = json.loads(frag.read_text())
            if f.get("fingerprint") == m["fingerprint"] and f.get("items"):
                per_item.append(f["seconds"] / len(f["items"]))
        if per_item:
            out["median_item_s"][m["stage"]] = statistics.median(per_item)
    return out


def tree_bytes(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())


def measure(frames: int, args: argparse.Namespace) -> dict:
    """Generate (once), label and inspect one sequence of ``frames`` frames."""
    work = args.work
    log = work / f"log-{args.sensor}-{frames}"
    out_log = work / f"commands-{frames}.log"
    res: dict = {"frames": frames, "sensor": args.sensor}
    if not (log / ".complete").is_file():
        shutil.rmtree(log, ignore_errors=True)
        synth = ["synth", str(log), "--sequences", "1", "--frames", str(frames), "--seed", "0"]
        wall, _, code, _ = dsnet([*synth, "--sensor", args.sensor], out_log)
        if code:
            sys.exit(f"dsnet synth failed: see {out_log}")
        (log / ".complete").touch()
        res["synth_s"] = wall
    run = work / f"run-{frames}"
    shutil.rmtree(run, ignore_errors=True)
    label = ["label", str(log), "--run", str(run), *args.label_args]
    res["label_s"], res["label_rss_mib"], code, res["label_cpu_s"] = dsnet(label, out_log)
    if code:  # keep what the finished stages measured; the commands need a finished run
        errors = [line for line in out_log.read_text().splitlines() if line.startswith("error:")]
        res["label_error"] = errors[-1] if errors else f"exit {code}: see {out_log}"
    res |= stage_times(run)
    res["store_bytes"] = {p.name: tree_bytes(p) for p in sorted((run / "sequences" / SEQ).iterdir())}
    res["store_bytes"]["tables"] = tree_bytes(run / "tables")
    res["store_bytes"]["(total)"] = tree_bytes(run)
    commands = [("status", [])]
    if not code:
        commands += [
            ("export", ["--out", str(work / f"preds-{frames}")]),
            ("dashboard", ["--out", str(run / "dashboard.html")]),
        ]
    for name, extra in commands:
        shutil.rmtree(work / f"preds-{frames}", ignore_errors=True)
        wall, rss, code, cpu = dsnet([name, str(run), *extra], out_log)
        res[f"{name}_s"], res[f"{name}_rss_mib"] = (wall, rss) if code == 0 else (float("nan"), rss)
        res[f"{name}_cpu_s"] = cpu
    return res


def report(results: list[dict]) -> None:
    """The per-length table, then every per-frame figure as a ratio to the shortest length."""
    print(
        "\n| frames | label s/frame | label CPU s/frame | stages s/frame | median blocks s/item "
        "| peak RSS MiB | store KiB/frame | status s (CPU) | export s (CPU) | dashboard s (CPU) |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    nan = float("nan")
    for r in results:
        n = r["frames"]
        blocks = sum(r["median_item_s"].values()) if "median_item_s" in r else nan
        print(
            f"| {n} | {r['label_s'] / n:.3f} | {r.get('label_cpu_s', nan) / n:.3f} | "
            f"{sum(r['stages_s'].values()) / n:.3f} | {blocks:.3f} | "
            f"{r['label_rss_mib']:.0f} | {r['store_bytes']['(total)'] / n / 1024:.0f} | "
            + " | ".join(
                f"{r.get(c + '_s', nan):.2f} ({r.get(c + '_cpu_s', nan):.2f})"
                for c in ("status", "export", "dashboard")
            )
            + " |"
        )
        if "label_error" in r:
            print(f"|   | label failed: {r['label_error']} (figures of the stages it finished) |")
    base = results[0]
    n0 = base["frames"]
    print(f"\nper-frame figures against {n0} frames (1.00 = linear in the frame count):")
    for r in results[1:]:
        n = r["frames"]
        k = n / n0
        rows = {} if "label_error" in r else {"label wall": r["label_s"] / base["label_s"] / k}
        if "label_cpu_s" in r and "label_cpu_s" in base and "label_error" not in r:
            rows["label CPU"] = r["label_cpu_s"] / base["label_cpu_s"] / k
        for key, name, per in (("stages_s", "stage", (n, n0)), ("median_item_s", "median block", (1, 1))):
            rows |= {
                f"{name} {s}": (r[key][s] / per[0]) / (base[key][s] / per[1])
                for s in r.get(key, {})
                if base.get(key, {}).get(s)
            }
        rows |= {
            f"store {s}": (b / n) / (base["store_bytes"][s] / n0)
            for s, b in r["store_bytes"].items()
            if base["store_bytes"].get(s) and "label_error" not in r
        }
        rows["label peak RSS (absolute)"] = r["label_rss_mib"] / base["label_rss_mib"]
        for c in ("status", "export", "dashboard"):
            if f"{c}_s" not in r:
                continue
            rows[f"{c} (absolute time)"] = r[f"{c}_s"] / base[f"{c}_s"]
            rows[f"{c} peak RSS (absolute)"] = r[f"{c}_rss_mib"] / base[f"{c}_rss_mib"]
        print(f"  {n} frames ({k:.0f}x): " + ", ".join(f"{name} {v:.2f}" for name, v in rows.items()))


def scale_main(argv: list[str]) -> None:
    ap = _parser("scale", SCALE_DOC)
    ap.add_argument("--lengths", default="100,300,1000")
    ap.add_argument("--sensor", default="vlp32")
    ap.add_argument("--work", type=Path, default=None, help="logs and runs (default: a new temp folder)")
    ap.add_argument("--json", type=Path, default=None, help="append each length's figures here")
    ap.add_argument("--label-args", default="", help="extra `dsnet label` options, e.g. '--scans 1'")
    ap.add_argument("--report", type=Path, default=None, help="only print the report of a --json file")
    args = ap.parse_args(argv)
    if args.report:  # runs kept in --work also give their blocks' times
        results = [json.loads(line) for line in args.report.read_text().splitlines() if line.strip()]
        for r in results:
            if args.work and (args.work / f"run-{r['frames']}").is_dir():
                r |= stage_times(args.work / f"run-{r['frames']}")
        report(results)
        return
    args.work = args.work or Path(tempfile.mkdtemp(prefix="bench-scale-"))
    args.work.mkdir(parents=True, exist_ok=True)
    args.label_args = args.label_args.split()
    results = []
    for frames in (int(v) for v in args.lengths.split(",")):
        r = measure(frames, args)
        results.append(r)
        print(json.dumps(r), flush=True)
        if args.json:
            with open(args.json, "a") as f:
                f.write(json.dumps(r) + "\n")
    report(results)
    print(f"\nlogs, runs and command output under {args.work}")


# -- dask --------------------------------------------------------------------------------------
DSNET = [sys.executable, "-m", "flows.cli"]


def dask_label(log: Path, run: Path, ckpt: Path, scans: int, env: dict, *extra: str) -> float:
    """Wall seconds of one ``dsnet label`` (fails loudly)."""
    cmd = [*DSNET, "label", str(log), "--run", str(run), "--scans", str(scans), "--checkpoint", str(ckpt)]
    t0 = time.perf_counter()
    res = subprocess.run(
        [*cmd, "--block-size", "1", *extra], cwd=ROOT, env=env, capture_output=True, text=True
    )
    wall = time.perf_counter() - t0
    if res.returncode != 0:
        raise SystemExit(f"dsnet label failed:\n{res.stdout[-3000:]}\n{res.stderr[-3000:]}")
    return wall


def dask_main(argv: list[str]) -> None:
    from flows.server import prefect_api
    from tests.helpers.cluster import start_cluster

    p = _parser("dask", DASK_DOC)
    p.add_argument("--sequences", type=int, default=4)
    p.add_argument("--frames", type=int, default=6)
    p.add_argument("--scans", type=int, default=2)
    args = p.parse_args(argv)
    tmp = Path(tempfile.mkdtemp(prefix="bench-dask-"))
    log = tmp / "log"
    subprocess.run(
        [*DSNET, "synth", str(log), "--sequences", str(args.sequences), "--frames", str(args.frames)],
        cwd=ROOT, check=True, capture_output=True,
    )  # fmt: skip
    ckpt = random_tiny_checkpoint(tmp / "tiny-random")
    frames = args.sequences * args.frames
    with prefect_api() as api:
        env = {**os.environ, "PYTHONPATH": str(ROOT), "PREFECT_API_URL": api, "OMP_NUM_THREADS": "1"}
        rows = [("threads (no Dask)", dask_label(log, tmp / "run-threads", ckpt, args.scans, env))]
        for n in (1, 2):
            cluster = start_cluster(tmp / f"dask-{n}", env, n_workers=n)
            try:
                wall = dask_label(
                    log, tmp / f"run-{n}", ckpt, args.scans, env, "--dask-address", cluster.address
                )
            finally:
                cluster.stop()
            rows.append((f"dask, {n} worker{'s' if n > 1 else ''}", wall))
    base = rows[1][1]
    print(f"{frames} hdl64 frames ({args.sequences} sequences), k = {args.scans}, tiny random weights")
    print(f"{'runner':<20}{'wall s':>9}{'frames/s':>10}{'× 1 worker':>12}")
    for name, wall in rows:
        print(f"{name:<20}{wall:>9.1f}{frames / wall:>10.2f}{base / wall:>12.2f}")


MODES = {"stages": stages_main, "overhead": overhead_main, "scale": scale_main, "dask": dask_main}


def main(argv: list[str]) -> None:
    if argv and argv[0] in MODES:
        MODES[argv[0]](argv[1:])
        return
    if argv:
        sys.exit(
            f"usage: bench_label.py [{'|'.join(MODES)}] [options]  (MODE --help: its options)\n{__doc__}"
        )
    for mode in MODES:  # each in its own process: torch threads, Prefect settings, peak RSS
        print(f"== bench_label.py {mode}", flush=True)
        subprocess.run([sys.executable, __file__, mode], check=True)


if __name__ == "__main__":
    main(sys.argv[1:])
