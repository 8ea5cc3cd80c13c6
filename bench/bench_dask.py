"""Throughput of ``dsnet label`` on a real Dask cluster: 1 vs 2 workers, next to the default
thread runner, in the same run.

Generates a synthetic log (``--sequences`` × ``--frames``, hdl64), builds a seeded random-weight
``tiny`` checkpoint, starts ``dask scheduler`` + N single-threaded ``dask worker`` processes on
loopback (tests/helpers/cluster.py: the same processes as the cluster tests) and runs
``dsnet label --dask-address`` into a fresh local run folder for N = 1 and N = 2, and once without
Dask (threads). Prints wall seconds, frames per second and the ratios; the Prefect server is a
temporary one for the whole bench. Each worker uses one torch thread; on a 2-core machine the
2-worker figure is bounded by the cores left to the scheduler, the flow process and the server.

Run: ``.venv/bin/python bench/bench_dask.py [--sequences 4] [--frames 6] [--scans 2]``
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from bench.bench_stages import random_tiny_checkpoint  # noqa: E402
from flows.server import prefect_api  # noqa: E402
from tests.helpers.cluster import start_cluster  # noqa: E402

DSNET = [sys.executable, "-m", "flows.cli"]


def label(log: Path, run: Path, ckpt: Path, scans: int, env: dict, *extra: str) -> float:
    """Wall seconds of one ``dsnet label`` (fails loudly)."""
    cmd = [*DSNET, "label", str(log), "--run", str(run), "--scans", str(scans), "--checkpoint", str(ckpt)]
    t0 = time.perf_counter()
    res = subprocess.run(
        [*cmd, "--block-size", "1", *extra], cwd=REPO, env=env, capture_output=True, text=True
    )
    wall = time.perf_counter() - t0
    if res.returncode != 0:
        raise SystemExit(f"dsnet label failed:\n{res.stdout[-3000:]}\n{res.stderr[-3000:]}")
    return wall


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--sequences", type=int, default=4)
    p.add_argument("--frames", type=int, default=6)
    p.add_argument("--scans", type=int, default=2)
    args = p.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="bench-dask-"))
    log = tmp / "log"
    subprocess.run(
        [*DSNET, "synth", str(log), "--sequences", str(args.sequences), "--frames", str(args.frames)],
        cwd=REPO, check=True, capture_output=True,
    )  # fmt: skip
    ckpt = random_tiny_checkpoint(tmp / "tiny-random")
    frames = args.sequences * args.frames
    with prefect_api() as api:
        env = {**os.environ, "PYTHONPATH": str(REPO), "PREFECT_API_URL": api, "OMP_NUM_THREADS": "1"}
        rows = [("threads (no Dask)", label(log, tmp / "run-threads", ckpt, args.scans, env))]
        for n in (1, 2):
            cluster = start_cluster(tmp / f"dask-{n}", env, n_workers=n)
            try:
                wall = label(log, tmp / f"run-{n}", ckpt, args.scans, env, "--dask-address", cluster.address)
            finally:
                cluster.stop()
            rows.append((f"dask, {n} worker{'s' if n > 1 else ''}", wall))
    base = rows[1][1]
    print(f"{frames} hdl64 frames ({args.sequences} sequences), k = {args.scans}, tiny random weights")
    print(f"{'runner':<20}{'wall s':>9}{'frames/s':>10}{'× 1 worker':>12}")
    for name, wall in rows:
        print(f"{name:<20}{wall:>9.1f}{frames / wall:>10.2f}{base / wall:>12.2f}")


if __name__ == "__main__":
    main()
