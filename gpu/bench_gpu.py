"""The model paths on a GPU: frames per second, the label stages per frame, training steps, memory.

On one device (``--device``, default ``cuda``; ``--device cpu`` runs the same code as a smoke
test on a machine without a GPU):

1. **Forward frames/s** at a preset's width (default ``paper``, 56.5 M parameters; random
   weights: the cost is the architecture's), k = 1 and k = 2 (two aligned scans), counting what
   lies between a scan in memory and its labels: voxelisation and the network
   (:class:`dsnet_core.model.inference.Predictor`), then dynamic shifting + clustering (FPS seeds,
   the shifting MLPs on ``--device`` — the dense kernel on CUDA —, the final mean shift) of the
   frame's thing points. Thing points are the ground truth's (a random network calls any point a
   thing; a trained one finds about these). A volume of k scans labels ``max(k − 1, 1)`` new
   frames (align's default stride), so frames/s = stride / seconds per volume. Warm-up first;
   CUDA timed with synchronisation.
2. **A training step** (batch 2, the ``joint`` stage: semantic + offset losses, forward + backward
   + Adam) with and without AMP (bf16, and fp16 with a scaler on CUDA): median seconds per step
   over the second epoch, and peak device memory.
3. **The label stages per frame** (ingest → track, ``dsnet label``'s k = 1 pipeline, through the
   plain runner; the ``--preset`` network on ``--device``; the shift stage itself runs on the CPU,
   as ``dsnet label --device cuda`` does today).

``--budget S`` skips the parts that would start after S seconds (each says so); ``--json PATH``
writes every figure for ``gpu/gpu_check.py``'s table. The synthetic log is generated on the fly
(hdl64, ~124 k points per frame).

Run on a GPU machine: ``PYTHONPATH=. python gpu/bench_gpu.py [--preset paper] [--frames 6]``
(``make gpu-check`` runs it with the wheels the machine lacks).
"""

from __future__ import annotations

import argparse
import json
import resource
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np
import torch

STAGES = ("ingest", "align", "infer", "shift", "fuse", "track")


def sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def timed(fn, device: torch.device, repeats: int) -> float:
    """Median seconds of ``fn()`` over ``repeats`` calls (after one warm-up)."""
    fn()
    out = []
    for _ in range(repeats):
        sync(device)
        t0 = time.perf_counter()
        fn()
        sync(device)
        out.append(time.perf_counter() - t0)
    return statistics.median(out)


def checkpoint(preset: str, path: Path) -> Path:
    from dsnet_core.labels import class_map_of, load_label_map
    from dsnet_core.model.checkpoint import ModelCard, save_checkpoint
    from dsnet_core.model.network import DSNet
    from dsnet_core.model.presets import get_preset

    torch.manual_seed(0)
    card = ModelCard(architecture={}, class_map=class_map_of(load_label_map("semantic-kitti")))
    return save_checkpoint(path, DSNet(get_preset(preset)), card)


def forward_rates(ckpt: Path, log: Path, device: torch.device, repeats: int) -> dict[str, dict]:
    """Per k: seconds per volume of the network and of shifting + clustering, and frames/s."""
    from dsnet_core.instance.clustering import get_clusterer
    from dsnet_core.instance.shifting import DynamicShift
    from dsnet_core.io.semantickitti import SemanticKittiReader
    from dsnet_core.labels import load_label_map
    from dsnet_core.model.inference import Predictor
    from dsnet_core.train.shifting import clusterer_for

    label_map = load_label_map("semantic-kitti")
    reader = SemanticKittiReader(log)
    refs = reader.frames("00")
    predictor = Predictor.from_checkpoint(ckpt, device=str(device))
    thing_lut = label_map.is_thing()
    out = {}
    for k in (1, 2):
        cloud = np.concatenate([reader.scan(r) for r in refs[:k]])  # poses ~identity over 2 frames
        raw = np.concatenate([reader.labels(r) for r in refs[:k]])
        sel = thing_lut[label_map.to_train(raw & 0xFFFF)]
        kernel = "dense" if device.type == "cuda" else "neighbors"
        cfg = clusterer_for(k).model_copy(
            update={"feature_dim": predictor.model.config.ins_dim, "device": str(device), "kernel": kernel}
        )
        weights = DynamicShift.with_fixed_weights(
            (0.0, 1.0, 0.0), cfg.bandwidths, iterations=cfg.iterations, feature_dim=cfg.feature_dim
        )
        clusterer = get_clusterer(cfg, weights)
        res = predictor.predict(cloud)
        xyz = np.ascontiguousarray(cloud[sel, :3])
        centres = np.ascontiguousarray(xyz + res.offsets[sel])
        feats = res.features[sel]
        net = timed(lambda cloud=cloud: predictor.predict(cloud), device, repeats)
        shift = timed(
            lambda c=clusterer, x=xyz, m=centres, f=feats: c.cluster(x, m, f) if len(x) else None,
            device,
            repeats,
        )
        stride = max(k - 1, 1)
        out[f"k{k}"] = {
            "points": len(cloud),
            "thing_points": int(sel.sum()),
            "network_s": net,
            "shift_s": shift,
            "frames_per_s": stride / (net + shift),
        }
    return out


def stage_seconds(ckpt: Path, log: Path, device: torch.device, tmp: Path) -> dict[str, float]:
    """Seconds per frame of each label stage (k = 1, tracked), the network on ``device``."""
    from storage.run import RunStore
    from tasks.methods import get_pipeline
    from tests.helpers.plain_runner import run_stage_plain

    p = get_pipeline("dsnet", temporal="track")
    store = RunStore(tmp / "run")
    run = {
        "data": str(log),
        "method_options": {"temporal": "track"},
        "stages": {"align": {"scans": 1}, "infer": {"checkpoint": str(ckpt), "device": str(device)}},
    }
    store.write_run_config("bench", run)
    per = {}
    for stage in STAGES:
        t0 = time.perf_counter()
        run_stage_plain(store, p, "00", stage, run, "bench")
        per[stage] = time.perf_counter() - t0
    n = store.read_manifest("00", "ingest").n_items
    return {s: v / n for s, v in per.items()}


def train_steps(preset: str, log: Path, device: torch.device, amp: str) -> dict[str, float]:
    """Median seconds per training step at batch 2 (second epoch) and peak device MiB, one AMP mode."""
    from dsnet_core.io.semantickitti import SemanticKittiReader
    from dsnet_core.labels import load_label_map
    from dsnet_core.model.presets import get_preset
    from dsnet_core.train.loop import TrainConfig, Trainer

    reader = SemanticKittiReader(log)
    cfg = TrainConfig(stage="joint", epochs={"joint": 2}, batch_size=2, device=str(device), amp=amp)
    out = Path(tempfile.mkdtemp(prefix=f"bench-gpu-train-{amp}-"))
    trainer = Trainer(
        out, get_preset(preset), reader, ["00"], reader, ["00"], load_label_map("semantic-kitti"), cfg
    )
    if device.type == "cuda":
        torch.cuda.reset_peak_memory_stats(device)
    times: list[float] = []
    last = [time.perf_counter()]

    def on_step(stage, epoch, step, total, loss) -> None:
        sync(device)
        now = time.perf_counter()
        if epoch == 2:
            times.append(now - last[0])
        last[0] = now

    opt = trainer.optimizer("joint")
    for epoch in range(2):  # the first epoch warms up (allocator, kernels, numba)
        sync(device)
        last[0] = time.perf_counter()
        trainer.train_epoch("joint", epoch, opt, on_step)
    if device.type == "cuda":
        peak, kind = torch.cuda.max_memory_allocated(device) / 2**20, "device"
    else:  # the process's peak resident memory (every mode so far), the nearest CPU figure
        peak, kind = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, "process RSS"
    return {"step_s": statistics.median(times), "peak_mib": peak, "peak_of": kind, "steps": len(times)}


def run(args: argparse.Namespace) -> dict:
    """Every part that fits ``args.budget``; the figures as a dict (see :func:`main`)."""
    start = time.perf_counter()
    device = torch.device(args.device)
    if device.type == "cuda" and not torch.cuda.is_available():
        raise SystemExit("no CUDA device here: run with --device cpu for a smoke test")
    if device.type == "cpu":
        torch.set_num_threads(1)
    from dsnet_core.synth import generate_log

    tmp = Path(tempfile.mkdtemp(prefix="bench-gpu-"))
    generate_log(tmp / "log", sequences=1, frames=args.frames, seed=0, sensor="hdl64")
    ckpt = checkpoint(args.preset, tmp / "ckpt")
    name = torch.cuda.get_device_name(device) if device.type == "cuda" else "cpu (1 thread)"
    res: dict = {"device": name, "preset": args.preset, "torch": torch.__version__, "skipped": []}
    res["setup_s"] = time.perf_counter() - start
    print(f"device: {name}; preset {args.preset}; torch {torch.__version__}", flush=True)

    def part(name: str, fn):
        if time.perf_counter() - start > args.budget:
            res["skipped"].append(name)
            print(f"{name}: skipped (past the {args.budget:.0f} s budget)", flush=True)
            return
        t0 = time.perf_counter()
        res[name] = fn()
        res[f"{name}_wall_s"] = time.perf_counter() - t0
        print(f"{name}: {json.dumps(res[name])}", flush=True)
        if args.json:  # after every part: a run killed later keeps what it measured
            args.json.write_text(json.dumps(res, indent=2))

    part("forward", lambda: forward_rates(ckpt, tmp / "log", device, args.repeats))
    modes = ["off", "bf16"] + (["fp16"] if device.type == "cuda" else [])
    part("train", lambda: {amp: train_steps(args.preset, tmp / "log", device, amp) for amp in modes})
    part("stages", lambda: stage_seconds(ckpt, tmp / "log", device, tmp))
    if device.type == "cuda" and torch.cuda.device_count() > 1:
        res["note"] = f"{torch.cuda.device_count()} GPUs: DDP (torchrun) scaling is not measured here"
    res["total_s"] = time.perf_counter() - start
    return res


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--device", default=None, help="cuda (default where one is present) or cpu (a smoke test)"
    )
    ap.add_argument("--preset", default="paper")
    ap.add_argument("--frames", type=int, default=6, help="frames of the generated log (even: batch 2)")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--budget", type=float, default=float("inf"), help="start no part after S seconds")
    ap.add_argument("--json", type=Path, default=None, help="write the figures here")
    args = ap.parse_args()
    if args.device is None:  # `make bench` runs it too: without CUDA it says so and skips
        if not torch.cuda.is_available():
            print("bench_gpu: skipped, no CUDA device here (--device cpu runs it as a smoke test)")
            return
        args.device = "cuda"
    res = run(args)
    if args.json:
        args.json.write_text(json.dumps(res, indent=2))
    for k, r in res.get("forward", {}).items():
        print(
            f"forward {k}: {r['frames_per_s']:.2f} frames/s (network {r['network_s']:.3f} s + shifting "
            f"and clustering {r['shift_s']:.3f} s per volume of {r['points']} points, "
            f"{r['thing_points']} thing)"
        )
    for amp, r in res.get("train", {}).items():
        print(
            f"train step (batch 2, amp {amp}): {r['step_s']:.3f} s, "
            f"peak {r['peak_of']} {r['peak_mib']:.0f} MiB"
        )
    if "stages" in res:
        per = res["stages"]
        cells = "  ".join(f"{s} {v:.3f}" for s, v in per.items())
        print(f"label stages, s/frame: {cells}  | total {sum(per.values()):.3f}")


if __name__ == "__main__":
    main()
