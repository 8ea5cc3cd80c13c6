"""How labelling grows with the length of a sequence: one generated sequence per length, labelled
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

Run: ``nice -n 19 .venv/bin/python bench/bench_scale.py --lengths 100,300,1000 [--sensor vlp32]
[--work DIR] [--json FILE]``.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--lengths", default="100,300,1000")
    ap.add_argument("--sensor", default="vlp32")
    ap.add_argument("--work", type=Path, default=None, help="logs and runs (default: a new temp folder)")
    ap.add_argument("--json", type=Path, default=None, help="append each length's figures here")
    ap.add_argument("--label-args", default="", help="extra `dsnet label` options, e.g. '--scans 1'")
    ap.add_argument("--report", type=Path, default=None, help="only print the report of a --json file")
    args = ap.parse_args()
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


if __name__ == "__main__":
    main()
