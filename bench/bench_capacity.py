"""Capacity within the CPU budget: steps per hour and validation mIoU per hour at several U-Net widths.

For each width of ``--widths`` (default 4, 6, 8) the DS-Net network of ``--preset`` (default
``tiny``, width 4) at that base width — only the width changes: point MLP, grid and inputs stay the
preset's — is trained from scratch by the real trainer (``dsnet train dsnet --width W``, called
in-process in a child process per width, one torch thread, one stream render worker) on the same
never-seen synthetic stream (``--stream STEPS``, the training styles and sensors of
``bench/bench_transfer.py``, the same ``--seed``): ``--steps`` semantic-stage steps, one epoch,
batch 1, the default learning rate and cosine schedule. The step callback stamps every step
(wall clock and the process's CPU time; the render worker is another process, so the CPU time is
the network's step alone). After the steps the trainer validates on a small fixed log generated
here with ``dsnet synth`` (the first ``--val-sequences`` setups of bench_transfer's ``seeds`` cell,
seed 303, sequences 60…, ``--val-frames`` frames each: seeds the stream never draws).

Reported per width: parameters; weights size (the trainer's fp32 ``model.safetensors``, MB =
10^6 bytes); seconds per step (median over the steps after the first ``--skip``, wall and CPU) and
its ratio to the first width; steps per hour (3600 / median wall s/step); validation mIoU after
the steps; mIoU per hour = val mIoU / the hours the steps took (first step to last, wall;
validation and start-up excluded). The widths run one after the other in the order given.

The machine this runs on is shared (2 cores, loaded by other trainings): absolute times are
indicative only; the ratios between widths (measured minutes apart, CPU time beside wall time)
are the result. A few dozen steps from scratch say little about converged quality: the mIoU
column says which width learns fastest at the very start, not which one ends best.

Run: ``OMP_NUM_THREADS=1 nice -n 10 .venv/bin/python bench/bench_capacity.py --out DIR
[--widths 4,6,8] [--steps 40] [--skip 5]``. Writes ``DIR/capacity.json`` and ``DIR/capacity.md``
and prints the table; the checkpoints stay under ``DIR/w<W>/`` (each run starts afresh).
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

BENCH = Path(__file__).resolve().parent
REPO = BENCH.parent
sys.path.insert(0, str(REPO))

TRAIN_STYLES = ("classic", "residential", "arterial", "downtown", "country")  # as bench_transfer
TRAIN_SENSORS = ("hdl64", "ouster64", "ouster128", "vlp16")
VAL_SEED, VAL_FIRST = 303, 60  # bench_transfer's ``seeds`` cell
VAL_SETUPS = (
    ("residential", "hdl64"),
    ("arterial", "ouster64"),
    ("downtown", "vlp16"),
    ("country", "hdl64"),
    ("classic", "ouster128"),
)


def step_seconds(stamps: list[float]) -> list[float]:
    """Durations of the steps from ``stamps``: the time before the first step, then one per step."""
    return [b - a for a, b in itertools.pairwise(stamps)]


def summarise(result: dict, skip: int) -> dict:
    """The table row of one width's child result (``wall`` / ``cpu`` stamps, ``val_miou``, ...).

    Raises:
        ValueError: fewer than ``skip + 1`` steps.
    """
    wall, cpu = step_seconds(result["wall"]), step_seconds(result["cpu"])
    if len(wall) <= skip:
        raise ValueError(f"width {result['width']}: {len(wall)} steps, need more than --skip {skip}")
    s_wall, s_cpu = statistics.median(wall[skip:]), statistics.median(cpu[skip:])
    hours = sum(wall) / 3600.0
    return {
        "width": result["width"],
        "parameters": result["parameters"],
        "weights_mb": result["weights_bytes"] / 1e6,
        "steps": len(wall),
        "s_per_step": s_wall,
        "cpu_s_per_step": s_cpu,
        "steps_per_hour": 3600.0 / s_wall,
        "train_hours": hours,
        "val_miou": result["val_miou"],
        "miou_per_hour": result["val_miou"] / hours,
        "load": result.get("load"),
    }


def with_ratios(rows: list[dict]) -> list[dict]:
    """``rows`` with ``ratio`` / ``cpu_ratio``: s/step (wall, CPU) over the first row's."""
    base = rows[0]
    return [
        {
            **r,
            "ratio": r["s_per_step"] / base["s_per_step"],
            "cpu_ratio": r["cpu_s_per_step"] / base["cpu_s_per_step"],
        }
        for r in rows
    ]


def markdown(rows: list[dict]) -> str:
    """The table of :func:`with_ratios` rows."""
    head = ["width", "parameters", "weights MB", "s/step", "× w" + str(rows[0]["width"]), "CPU s/step"]
    head += ["CPU ×", "steps/h", "val mIoU", "mIoU/h"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        cells = [str(r["width"]), f"{r['parameters'] / 1e6:.2f} M", f"{r['weights_mb']:.1f}"]
        cells += [f"{r['s_per_step']:.2f}", f"{r['ratio']:.2f}", f"{r['cpu_s_per_step']:.2f}"]
        cells += [f"{r['cpu_ratio']:.2f}", f"{r['steps_per_hour']:.0f}", f"{r['val_miou']:.4f}"]
        cells.append(f"{r['miou_per_hour']:.3f}")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def make_val(root: Path, sequences: int, frames: int) -> Path:
    """The validation log: the first ``sequences`` setups of the ``seeds`` cell (kept while current)."""
    out = root / "val"
    stamp = out / "bench_cell.json"
    want = {"seed": VAL_SEED, "first": VAL_FIRST, "setups": VAL_SETUPS[:sequences], "frames": frames}
    if stamp.exists() and json.loads(stamp.read_text()) == json.loads(json.dumps(want)):
        return out
    from dsnet_core.synth import generate_log

    for i, (style, sensor) in enumerate(VAL_SETUPS[:sequences]):
        generate_log(out, sequences=1, frames=frames, seed=VAL_SEED, sensor=sensor, style=style,
                     first_sequence=VAL_FIRST + i, overwrite=True)  # fmt: skip
    stamp.write_text(json.dumps(want) + "\n")
    return out


class _Stamps:
    """The trainer's step callback: wall and CPU time before the first step and after every step."""

    def __init__(self) -> None:
        self.wall: list[float] = []
        self.cpu: list[float] = []

    def _stamp(self) -> None:
        self.wall.append(time.perf_counter())
        self.cpu.append(time.process_time())

    def start(self, stage: str, epoch: int, steps: int) -> None:
        self._stamp()

    def __call__(self, stage: str, epoch: int, step: int, steps: int, loss: float) -> None:
        self._stamp()


def child(args: argparse.Namespace) -> None:
    """Train one width (``--child W``) and write ``DIR/w<W>/bench_child.json``."""
    import logging

    from dsnet_core.model.checkpoint import read_card
    from dsnet_core.model.network import DSNet
    from tasks.methods import get_method
    from tasks.methods.dsnet_train import DsnetTrainOptions, model_config

    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(message)s")
    out = Path(args.out) / f"w{args.child}"
    options = DsnetTrainOptions(
        out=out, stream=args.steps, stream_styles=",".join(TRAIN_STYLES),
        stream_sensors=",".join(TRAIN_SENSORS), val_data=Path(args.out) / "val", epochs="semantic=1",
        stage="semantic", preset=args.preset, width=args.child, seed=args.seed, threads=1,
    )  # fmt: skip
    stamps = _Stamps()
    load = os.getloadavg()[0]
    get_method("dsnet").train(options, stamps)
    card = read_card(out)
    result = {
        "width": args.child,
        "parameters": sum(p.numel() for p in DSNet(model_config(options)).parameters()),
        "weights_bytes": (out / "model.safetensors").stat().st_size,
        "val_miou": card.metrics[-1]["val_miou"],
        "epoch_seconds": card.metrics[-1].get("seconds"),
        "wall": stamps.wall,
        "cpu": stamps.cpu,
        "load": [load, os.getloadavg()[0]],
    }
    (out / "bench_child.json").write_text(json.dumps(result) + "\n")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", required=True, help="working folder (validation log, checkpoints, results)")
    p.add_argument("--widths", default="4,6,8", help="comma-separated U-Net base widths")
    p.add_argument("--steps", type=int, default=40, help="semantic-stage steps per width")
    p.add_argument("--skip", type=int, default=5, help="first steps left out of the median")
    p.add_argument("--preset", default="tiny", help="the preset whose width is varied")
    p.add_argument("--seed", type=int, default=0, help="training seed (initialisation and stream)")
    p.add_argument("--val-sequences", type=int, default=2, choices=range(1, len(VAL_SETUPS) + 1))
    p.add_argument("--val-frames", type=int, default=2, help="frames per validation sequence")
    p.add_argument("--child", type=int, help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.child is not None:
        child(args)
        return
    widths = [int(w) for w in args.widths.split(",")]
    if args.steps <= args.skip:
        raise SystemExit(f"--steps {args.steps} must exceed --skip {args.skip}")
    root = Path(args.out)
    root.mkdir(parents=True, exist_ok=True)
    make_val(root, args.val_sequences, args.val_frames)
    results = []
    for w in widths:
        shutil.rmtree(root / f"w{w}", ignore_errors=True)
        cmd = [sys.executable, __file__, "--out", str(root), "--child", str(w), "--steps", str(args.steps)]
        cmd += ["--preset", args.preset, "--seed", str(args.seed)]
        t0 = time.perf_counter()
        res = subprocess.run(cmd, capture_output=True, text=True, env={**os.environ, "PYTHONPATH": str(REPO)})
        if res.returncode != 0:
            raise SystemExit(f"width {w}: training failed:\n{res.stderr[-3000:]}")
        results.append(json.loads((root / f"w{w}" / "bench_child.json").read_text()))
        print(f"width {w}: {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    rows = with_ratios([summarise(r, args.skip) for r in results])
    table = markdown(rows)
    settings = {k: getattr(args, k) for k in ("widths", "steps", "skip", "preset", "seed")}
    settings |= {"val_sequences": args.val_sequences, "val_frames": args.val_frames}
    (root / "capacity.json").write_text(
        json.dumps({"settings": settings, "rows": rows, "runs": results}) + "\n"
    )
    (root / "capacity.md").write_text(table + "\n")
    print(table)


if __name__ == "__main__":
    main()
