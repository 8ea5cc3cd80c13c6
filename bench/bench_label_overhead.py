"""Orchestration + store overhead of ``label_sequence`` vs the same stage functions in a plain loop.

Runs on a synthetic 100-frame sequence (tests/logs.py's parked-car street, ~120k points a frame):
    compute   the stage's core work with no store: read + check every scan, checksum, build volumes;
    plain     the stage runner in a plain loop (prepare, every block, finalise: all store writes,
              no Prefect, no locks);
    flow      ``label_sequence`` on a running Prefect server (server start-up excluded, reported),
              with one worker thread (same parallelism as the loop) and with the default pool;
    no-op     the rerun of the finished sequence: the store work (skip decisions), and the whole flow.

    .venv/bin/python bench/bench_label_overhead.py [--frames 100] [--points 120000] [--scans 2]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

from tests.helpers.label_request import req

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from flows.server import quiet_prefect_env
from tasks.methods import get_pipeline

P = get_pipeline()  # the DS-Net stages

quiet_prefect_env()


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


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--points", type=int, default=120_000)
    ap.add_argument("--scans", type=int, default=2)
    ap.add_argument("--block-size", type=int, default=25)
    ap.add_argument("--rounds", type=int, default=2)
    args = ap.parse_args()

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
    from tasks.runner import prepare_stage, run_stage_plain

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


if __name__ == "__main__":
    main()
