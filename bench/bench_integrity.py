"""What checking a finished run store costs: the cheap check (the skip decision, ``dsnet status``,
``dsnet export``) and the full one (``dsnet status --verify``), per stage and per frame.

Labels one sequence of a synthetic VLP-32 log with the seeded tiny checkpoint and the fast
clusterer (the plain runner, no Prefect), at two sizes, then times ``RunStore.check_stage`` on
every stage (best of 5); the difference between the sizes gives the cost per frame.

    .venv/bin/python bench/bench_integrity.py [--frames 10 40]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from dsnet_core.synth import generate_log
from storage.run import RunStore
from tasks.methods import get_pipeline
from tests.helpers.label_request import req
from tests.helpers.plain_runner import run_stage_plain
from tests.model_helpers import make_checkpoint

P = get_pipeline()
FAST_SHIFT = {"kind": "dynamic_shift", "n_seeds": 300, "bandwidths": [0.2, 1.8, 3.4]}


def label(tmp: Path, frames: int, ckpt: Path) -> tuple[RunStore, float]:
    log = tmp / f"log{frames}"
    generate_log(log, sequences=1, frames=frames, seed=0, sensor="vlp32")
    store = RunStore(tmp / f"run{frames}")
    stages = {"align": {"scans": 1}, "infer": {"checkpoint": str(ckpt)}, "shift": {"clusterer": FAST_SHIFT}}
    run = {"data": str(log), "stages": req(log, store.uri, stages=stages).stage_configs(P)}
    store.write_run_config("bench", run)
    t0 = time.perf_counter()
    for stage in P.names():
        run_stage_plain(store, P, "00", stage, run, "bench")
    return store, time.perf_counter() - t0


def check_ms(store: RunStore, full: bool) -> dict[str, float]:
    out = {}
    for stage in P.names():
        m = store.read_manifest("00", stage)
        best = float("inf")
        for _ in range(5):
            t0 = time.perf_counter()
            damage = store.check_stage("00", P[stage].contract, m, full=full)
            best = min(best, time.perf_counter() - t0)
        assert not damage, damage
        out[stage] = 1000 * best
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, nargs=2, default=(10, 40))
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        ckpt = make_checkpoint(tmp / "ckpt", seed=0)
        totals = {}
        for frames in args.frames:
            store, seconds = label(tmp, frames, ckpt)
            print(f"{frames} frames: labelled in {seconds:.1f} s")
            for full in (False, True):
                ms = check_ms(store, full)
                totals[frames, full] = sum(ms.values())
                per = ", ".join(f"{k} {v:.1f}" for k, v in ms.items())
                print(f"  {'full ' if full else 'cheap'} {sum(ms.values()):7.1f} ms  ({per})")
        a, b = args.frames
        for full in (False, True):
            slope = (totals[b, full] - totals[a, full]) / (b - a)
            fixed = totals[a, full] - a * slope
            print(f"{'full' if full else 'cheap'}: {slope:.1f} ms per frame, {fixed:.0f} ms fixed")


if __name__ == "__main__":
    main()
