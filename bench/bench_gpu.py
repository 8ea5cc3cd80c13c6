"""The model paths on a GPU: frames per second, the label stages per frame, training steps, memory.

On one device (``--device``, default ``cuda``; ``--device cpu`` runs the same code as a smoke
test on a machine without a GPU):

1. **Forward frames/s** at a preset's width (default ``paper``, 56.5 M parameters in the
   reference; random weights: the cost is the architecture's), k = 1 and k = 2 (two aligned
   scans), counting what lies between a scan in memory and its labels: voxelisation, the network,
   dynamic shifting + clustering (:class:`dsnet_core.model.inference.Predictor` and the shift
   stage's clusterer). Warm-up passes first; CUDA timed with synchronisation.
2. **The label stages per frame** (ingest → stitch through the plain runner, the ``--preset``
   network on ``--device``): seconds per frame per stage.
3. **A training step** (batch 2, semantic + offset losses, forward + backward + Adam) with and
   without AMP (bf16, and fp16 with a scaler on CUDA): seconds per step and peak device memory.
4. With several GPUs: a note on DDP (``torchrun``) — not built yet.

Run on a GPU machine: ``PYTHONPATH=. python bench/bench_gpu.py [--preset paper] [--frames 5]``
(the synthetic log is generated on the fly: hdl64, ~124 k points per frame).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np
import torch

STAGES = ("ingest", "align", "infer", "shift", "fuse", "stitch")


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


def forward_rates(ckpt: Path, log: Path, device: torch.device, repeats: int) -> dict[int, float]:
    """k -> frames/s of voxelisation + network + dynamic shifting + clustering."""
    from dsnet_core.instance.clustering import get_clusterer
    from dsnet_core.instance.shifting import DynamicShift
    from dsnet_core.io.semantickitti import SemanticKittiReader
    from dsnet_core.labels import load_label_map
    from dsnet_core.model.inference import Predictor
    from dsnet_core.train.shifting import clusterer_for

    reader = SemanticKittiReader(log)
    refs = reader.frames("00")
    predictor = Predictor.from_checkpoint(ckpt, device=str(device))
    thing_lut = load_label_map("semantic-kitti").is_thing()
    out = {}
    for k in (1, 2):
        cloud = np.concatenate([reader.scan(r) for r in refs[:k]])  # poses ~identity over 2 frames
        cfg = clusterer_for(k).model_copy(update={"feature_dim": predictor.model.config.ins_dim})
        weights = DynamicShift.with_fixed_weights(
            (0.0, 1.0, 0.0), cfg.bandwidths, iterations=cfg.iterations, feature_dim=cfg.feature_dim
        )
        clusterer = get_clusterer(cfg, weights)

        def once(cloud=cloud, clusterer=clusterer) -> None:
            res = predictor.predict(cloud)
            sel = thing_lut[res.sem]
            xyz = np.ascontiguousarray(cloud[sel, :3])
            if sel.any():
                clusterer.cluster(xyz, np.ascontiguousarray(xyz + res.offsets[sel]), res.features[sel])

        out[k] = k / timed(once, device, repeats)
    return out


def stage_seconds(ckpt: Path, log: Path, device: torch.device, tmp: Path) -> dict[str, float]:
    from storage.run import RunStore
    from tasks.methods import get_pipeline
    from tasks.runner import run_stage_plain

    p = get_pipeline()
    store = RunStore(tmp / "run")
    run = {
        "data": str(log),
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


def train_steps(preset: str, log: Path, device: torch.device, amp: str, steps: int) -> tuple[float, float]:
    """(seconds per training step at batch 2, peak device MB) for one AMP mode."""
    from dsnet_core.io.semantickitti import SemanticKittiReader
    from dsnet_core.labels import load_label_map
    from dsnet_core.model.presets import get_preset
    from dsnet_core.train.loop import TrainConfig, Trainer

    reader = SemanticKittiReader(log)
    cfg = TrainConfig(stage="semantic", epochs={"semantic": 1}, batch_size=2, device=str(device), amp=amp)
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
        times.append(now - last[0])
        last[0] = now

    trainer.train_epoch("semantic", 0, trainer.optimizer("semantic"), on_step)
    peak = torch.cuda.max_memory_allocated(device) / 2**20 if device.type == "cuda" else float("nan")
    return statistics.median(times[1:] or times), peak


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cuda")
    ap.add_argument("--preset", default="paper")
    ap.add_argument("--frames", type=int, default=6)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
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
    print(f"device: {name}; preset {args.preset}; torch {torch.__version__}")
    for k, rate in forward_rates(ckpt, tmp / "log", device, args.repeats).items():
        print(f"forward k = {k}: {rate:.2f} frames/s (voxelisation + network + shifting + clustering)")
    per = stage_seconds(ckpt, tmp / "log", device, tmp)
    print(
        "label stages, s/frame: "
        + "  ".join(f"{s} {v:.3f}" for s, v in per.items())
        + f"  | total {sum(per.values()):.3f}"
    )
    modes = ["off", "bf16"] + (["fp16"] if device.type == "cuda" else [])
    for amp in modes:
        step, peak = train_steps(args.preset, tmp / "log", device, amp, args.frames)
        print(f"train step (batch 2, amp {amp}): {step:.3f} s, peak {peak:.0f} MB")
    if device.type == "cuda" and torch.cuda.device_count() > 1:
        print(f"{torch.cuda.device_count()} GPUs: DDP (torchrun) scaling is not built yet")


if __name__ == "__main__":
    main()
