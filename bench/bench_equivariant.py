"""Cost of Eq-4D's C_n lifting: forward time, training-step time and peak memory against n.

The equivariant network runs its backbone on n rotated copies of the cloud (shared weights), so
time and activation memory should grow about linearly with n; ``--tta n`` (an ordinary model
averaged over n rotations) costs n plain forwards. Each n runs in its own process (its own peak
RSS); times are medians of ``--repeat`` passes after one warm-up, one torch thread, and every
ratio is against n = 1 measured in the same run.

Run: ``OMP_NUM_THREADS=1 .venv/bin/python bench/bench_equivariant.py [--n 1,2,4,8] [--preset tiny]
[--points 120000] [--repeat 3] [--train]``
"""

from __future__ import annotations

import argparse
import json
import resource
import statistics
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def one(n: int, preset: str, points: int, repeat: int, train: bool) -> dict:
    """Forward (and training-step) seconds and peak RSS of a C_n network on one synthetic frame."""
    import torch

    from dsnet_core.model.network import DSNet
    from dsnet_core.model.presets import get_preset
    from dsnet_core.synth import generate_log

    torch.set_num_threads(1)
    import tempfile

    from dsnet_core.io.semantickitti import SemanticKittiReader

    root = Path(tempfile.mkdtemp(prefix="bench-eq-"))
    generate_log(root, sequences=1, frames=1, seed=0, sensor="hdl64")
    scan = SemanticKittiReader(root).scan(SemanticKittiReader(root).frames("00")[0])[:points]
    cloud = torch.from_numpy(scan)
    torch.manual_seed(0)
    net = DSNet(replace(get_preset(preset), equivariant=n))
    net.eval()
    with torch.inference_mode():
        net([cloud])
        times = []
        for _ in range(repeat):
            t0 = time.perf_counter()
            net([cloud])
            times.append(time.perf_counter() - t0)
    out = {"n": n, "points": int(cloud.shape[0]), "forward_s": statistics.median(times)}
    if train:
        net.train()
        opt = torch.optim.Adam(net.parameters(), lr=1e-4)
        steps = []
        for _ in range(repeat + 1):
            t0 = time.perf_counter()
            res = net([cloud])
            loss = res.logits.float().square().mean() + res.offsets.square().mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
            steps.append(time.perf_counter() - t0)
        out["train_step_s"] = statistics.median(steps[1:])
    out["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", default="1,2,4,8")
    ap.add_argument("--preset", default="tiny")
    ap.add_argument("--points", type=int, default=120_000)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--train", action="store_true", help="also time a training step (forward + backward)")
    ap.add_argument("--one", type=int, default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one is not None:
        print("ROW " + json.dumps(one(args.one, args.preset, args.points, args.repeat, args.train)))
        return
    rows = []
    for n in (int(v) for v in args.n.split(",")):
        cmd = [
            sys.executable,
            __file__,
            "--one",
            str(n),
            "--preset",
            args.preset,
            "--points",
            str(args.points),
        ]
        cmd += ["--repeat", str(args.repeat)] + (["--train"] if args.train else [])
        res = subprocess.run(cmd, capture_output=True, text=True, check=True)
        rows.append(json.loads([x for x in res.stdout.splitlines() if x.startswith("ROW ")][-1][4:]))
    base = rows[0]
    print(f"C_n lifting, preset {args.preset}, {base['points']} points, one thread (ratios: n = {base['n']})")
    head = "| n | forward s | × | peak RSS MB | × |" + (" train step s | × |" if args.train else "")
    print(head)
    print("|" + "---|" * (head.count("|") - 1))
    for r in rows:
        cells = [str(r["n"]), f"{r['forward_s']:.2f}", f"{r['forward_s'] / base['forward_s']:.2f}"]
        cells += [f"{r['peak_rss_mb']:.0f}", f"{r['peak_rss_mb'] / base['peak_rss_mb']:.2f}"]
        if args.train:
            cells += [f"{r['train_step_s']:.2f}", f"{r['train_step_s'] / base['train_step_s']:.2f}"]
        print("| " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
