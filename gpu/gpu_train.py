"""``make gpu-train OUT=DIR``: a time-boxed training run on a GPU machine that a later run resumes.

Trains the widest preset whose checkpoint can go back and forth between GPU machines — returned as
≤ 8 files of ≤ 16 MiB, carried back next to the working tree and the wheels (gpu/ckpt_parts.py:
float32 weights within 24 MiB, so ``small``, 3.6 M parameters, 13.7 MiB; ``paper``'s are 216 MiB)
— on the synthetic stream, rendered by one background process per spare CPU core, with the bundled
``tiny-v2``'s recipe (dsnet_core/data/models/README.md): its five street styles and four sensors,
its six validation sequences (seed 202, sequences 50–55), semantic 8 → instance head 3 → shifting
2 epochs, Adam at 1e-3 on a cosine schedule per stage, seed 0 — from scratch, as no narrower
checkpoint starts a wider network. An epoch is as many stream samples as the machine trains in
about ``--epoch-seconds`` (measured at the start of a new run, then fixed in the card: a resumed
run draws exactly what an uninterrupted one would), and every epoch is a checkpoint. After each,
the checkpoint is packed into ``OUT`` (gpu/ckpt_parts.py: tar parts, the card and
``metrics.csv``, the validation curve); the run stops before an epoch that would not end within
``--budget``. Run it again with the same ``OUT`` (on this machine or another) to continue: the
schedule, preset and samples per epoch then come from the card.

Imports no prefect, zarr or pydantic of its own (dsnet_core's configs use pydantic: it comes with
the wheels of ``make gpu-wheels``). ``--device cpu`` with ``--preset tiny`` and a short budget is
the smoke mode for a machine without a GPU.

Run: ``python3 gpu/gpu_train.py --out DIR [--budget 450] [--device cuda]``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import ckpt_parts
from gpu_wheels import DEFAULT_WHEELS, WheelError, activate

STYLES = ("classic", "residential", "arterial", "downtown", "country")
SENSORS = ("hdl64", "ouster64", "ouster128", "vlp16")
VAL = (  # tiny-v2's validation log: (style, sensor) of sequences 50..55, seed 202
    ("residential", "hdl64"),
    ("arterial", "ouster64"),
    ("downtown", "vlp16"),
    ("country", "ouster128"),
    ("classic", "hdl64"),
    ("downtown", "ouster64"),
)
RECIPE_EPOCHS = "semantic=8,offset=3,shift=2"
START = time.perf_counter()


class BudgetReached(Exception):
    """The run stopped for time; the last finished epoch is packed in OUT."""


def parse_epochs(text: str) -> dict[str, int]:
    """``"semantic=8,offset=3,shift=2"`` → per stage (unnamed stages 0)."""
    out = {"semantic": 0, "offset": 0, "joint": 0, "shift": 0}
    for part in text.split(","):
        name, _, value = part.partition("=")
        if name.strip() not in out or not value.strip().isdigit():
            raise SystemExit(f"error: --epochs {text!r}: expected e.g. {RECIPE_EPOCHS}")
        out[name.strip()] = int(value)
    return out


def widest_preset(limit: int = ckpt_parts.CARRY_BYTES - 2**20) -> tuple[str, int]:
    """The widest named preset whose float32 weights (4 bytes per parameter) fit ``limit`` bytes
    (with a MiB for the card and the shifting MLPs); (name, parameters)."""
    from dsnet_core.model.network import DSNet
    from dsnet_core.model.presets import PRESETS

    best = None
    for name, cfg in sorted(PRESETS.items(), key=lambda kv: kv[1].width):
        params = sum(p.numel() for p in DSNet(cfg).parameters())
        if 4 * params <= limit and (best is None or cfg.width > best[2]):
            best = (name, params, cfg.width)
    if best is None:
        raise SystemExit(f"error: no preset's weights fit {limit / 2**20:.0f} MiB")
    return best[0], best[1]


def make_val(root: Path, frames: int, workers: int) -> Path:
    """tiny-v2's six validation sequences (``frames`` each), rendered in parallel processes."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    from dsnet_core.synth import generate_log

    if (root / ".complete").is_file():
        return root
    ctx = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max(1, min(workers, len(VAL))), mp_context=ctx) as pool:
        kw = dict(sequences=1, frames=frames, seed=202, overwrite=True)
        jobs = [
            pool.submit(generate_log, root, first_sequence=50 + i, style=s, sensor=x, **kw)
            for i, (s, x) in enumerate(VAL)
        ]
        for job in jobs:
            job.result()
    (root / ".complete").touch()
    return root


def val_folder(frames: int) -> Path:
    """Where the validation log is cached: per frame count and version of the generator's code."""
    import hashlib

    synth = Path(__file__).resolve().parents[1] / "dsnet_core" / "synth"
    digest = hashlib.sha256(b"".join(p.read_bytes() for p in sorted(synth.rglob("*.py")))).hexdigest()
    return Path(tempfile.gettempdir()) / f"dsnet-gpu-train-val-{frames}-{digest[:10]}"


def calibrate(trainer, device: str) -> float:
    """Samples per second of the semantic stage's training (rendering included), from the steps
    after the first two of a throwaway epoch."""
    import torch

    marks: list[float] = []

    def on_step(stage, epoch, step, total, loss) -> None:
        if device.startswith("cuda"):
            torch.cuda.synchronize()
        marks.append(time.perf_counter())

    opt = trainer.optimizer("semantic")
    trainer.train_epoch("semantic", 0, opt, on_step, trainer.wrap())
    if len(marks) < 3:
        return 1.0 / (marks[-1] - marks[0] + 1e-9) if len(marks) > 1 else 0.1
    return (len(marks) - 2) / (marks[-1] - marks[1])


def make_trainer_class(base):
    """A :class:`~dsnet_core.train.loop.Trainer` that packs every committed epoch into ``export``
    and stops (:class:`BudgetReached`) before an epoch that would end after ``deadline``."""

    class BudgetTrainer(base):
        export: Path
        deadline: float
        mark: float
        stop_after: int = 0
        longest: float = 0.0
        epochs_here: int = 0

        def save(self, stage, epochs_done, opt, **extra) -> None:
            super().save(stage, epochs_done, opt, **extra)
            ckpt_parts.pack(self.out, self.export)
            now = time.perf_counter()
            self.longest = max(self.longest, now - self.mark)
            self.mark = now
            print(f"{stage} epoch {epochs_done} packed into {self.export} ({elapsed()})", flush=True)
            self.epochs_here += 1
            if self.stop_after and self.epochs_here >= self.stop_after:
                raise BudgetReached(
                    f"stopped after {stage} epoch {epochs_done} (--stop-after {self.stop_after})"
                )
            if self.deadline - now < 1.25 * self.longest + 5:
                raise BudgetReached(f"stopped after {stage} epoch {epochs_done}: the next would not fit")

    return BudgetTrainer


def parse_args() -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True, help="packed checkpoint folder (new, or to resume)")
    ap.add_argument("--device", default="cuda")
    ap.add_argument("--wheels", type=Path, default=DEFAULT_WHEELS)
    ap.add_argument("--budget", type=float, default=450.0, help="seconds for the whole run")
    ap.add_argument("--preset", default="auto", help="auto: the widest whose weights can be carried")
    ap.add_argument("--epochs", default=RECIPE_EPOCHS)
    ap.add_argument("--lr", type=float, default=1e-3)
    ap.add_argument("--amp", default="off", help="off | bf16 | fp16 (CUDA)")
    ap.add_argument("--batch-size", type=int, default=1)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--workers", type=int, default=max(1, (os.cpu_count() or 2) - 1))
    ap.add_argument("--epoch-seconds", type=float, default=60.0, help="target length of an epoch")
    ap.add_argument("--samples-per-epoch", type=int, default=0, help="0: measured at the start")
    ap.add_argument("--val-frames", type=int, default=4, help="frames per validation sequence")
    ap.add_argument("--stop-after", type=int, default=0, help="stop after N epochs in this run (0: budget)")
    return ap.parse_args()


def plan(args: argparse.Namespace, ckpt: Path) -> dict:
    """What this run trains: a new run from the flags, a resumed one from the card in ``args.out``
    (unpacked into ``ckpt``; then only ``--device``, ``--budget`` and ``--workers`` apply)."""
    from dsnet_core.model.presets import ModelConfig, get_preset
    from dsnet_core.train.loop import TrainConfig

    if ckpt_parts.exists(args.out):
        manifest = ckpt_parts.unpack(args.out, ckpt)
        if manifest.get("left_out"):
            print(f"optimiser state not in {args.out} ({manifest['left_out']['why']}): Adam restarts")
        card = json.loads((ckpt / "card.json").read_text())
        tc = {k: v for k, v in card["training_data"]["train_config"].items() if k != "world_size"}
        stream = card["training_data"]["stream"]
        lists = [tuple(v) if isinstance(v, list) else None for v in (stream["styles"], stream["sensors"])]
        print(f"resuming {args.out}: epochs done {card['epochs']} of {tc['epochs']} (the card's schedule)")
        return {
            "resume": True,
            "model": ModelConfig.from_dict(card["architecture"]),
            "train": TrainConfig(**{**tc, "device": args.device}),
            "samples": stream["samples_per_epoch"],
            "seed": stream["seed"],
            "styles": lists[0],
            "sensors": lists[1],
        }
    preset = args.preset
    if preset == "auto":
        preset, params = widest_preset()
        print(f"preset {preset} ({params / 1e6:.2f} M parameters): the widest whose checkpoint fits")
    cfg = TrainConfig(
        stage="all", epochs=parse_epochs(args.epochs), lr=args.lr, batch_size=args.batch_size,
        seed=args.seed, device=args.device, amp=args.amp,
    )  # fmt: skip
    return {
        "resume": False,
        "model": get_preset(preset),
        "train": cfg,
        "samples": args.samples_per_epoch,
        "seed": args.seed,
        "styles": STYLES,
        "sensors": SENSORS,
    }


def train(args: argparse.Namespace, run: dict, ckpt: Path) -> str | None:
    """Calibrate (a new run), then train until done or out of time; returns why it stopped early."""
    from dsnet_core.io.formats import open_log
    from dsnet_core.labels import load_label_map
    from dsnet_core.synth.stream import StreamOptions
    from dsnet_core.train.loop import Trainer
    from dsnet_core.train.stream import StreamLog

    label_map = load_label_map("semantic-kitti")
    val = make_val(val_folder(args.val_frames), args.val_frames, 6)
    val_reader = open_log(val, options={"label_map": label_map})
    vseqs = val_reader.sequences()
    print(f"validation: {len(vseqs)} sequences x {args.val_frames} frames ({elapsed()})")
    options = StreamOptions(frames=1, styles=run["styles"], sensors=run["sensors"])
    reader = StreamLog(run["seed"], options, run["samples"] or max(8, 2 * args.workers), args.workers)
    deadline = START + args.budget
    try:
        probe = reader.probe()
        reader.prefetch(probe)
        if not run["samples"]:
            with tempfile.TemporaryDirectory(prefix="dsnet-gpu-calibrate-") as tmp:
                trial = Trainer(tmp, run["model"], reader, probe, val_reader, vseqs, label_map, run["train"])
                rate = calibrate(trial, args.device)
            reader.steps = max(4, int(rate * args.epoch_seconds * 0.85))  # fixed: the card records it
            print(f"{rate:.2f} samples/s: {reader.steps} samples per epoch ({elapsed()})")
            reader.prefetch(probe)
        trainer = make_trainer_class(Trainer)(
            ckpt,
            run["model"],
            reader,
            probe,
            val_reader,
            vseqs,
            label_map,
            run["train"],
            resume=run["resume"],
        )
        trainer.export, trainer.deadline, trainer.mark = args.out, deadline, time.perf_counter()
        trainer.stop_after = args.stop_after

        def watchdog(stage, epoch, step, total, loss) -> None:
            if time.perf_counter() > deadline - 5:
                raise BudgetReached(f"stopped in {stage} epoch {epoch} at step {step}/{total}: out of time")

        trainer.run(on_step=watchdog)
    except BudgetReached as exc:
        return str(exc)
    finally:
        reader.close()
    return None


def elapsed() -> str:
    return f"{time.perf_counter() - START:.0f} s"


def main() -> None:
    args = parse_args()
    try:
        activate(args.wheels)
    except WheelError as exc:
        sys.exit(f"error: {exc}")
    import logging

    import torch

    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s", datefmt="%H:%M:%S")
    if args.device.startswith("cuda") and not torch.cuda.is_available():
        sys.exit("error: no CUDA device here: use --device cpu for a smoke run")
    torch.set_num_threads(1 if args.device == "cpu" else 2)  # the other cores render the stream
    ckpt = Path(tempfile.mkdtemp(prefix="dsnet-gpu-train-")) / "ckpt"
    try:
        run = plan(args, ckpt)
    except ckpt_parts.PartsError as exc:
        sys.exit(f"error: {exc}")
    stopped = train(args, run, ckpt)
    summary(args.out, run["train"].epochs, stopped)


def summary(out: Path, planned: dict[str, int], stopped: str | None) -> None:
    """The validation curve, the files in ``out`` and what to run next."""
    if not ckpt_parts.exists(out):
        print(f"no epoch finished within the budget: nothing written to {out}")
        sys.exit(1)
    card = json.loads((out / "card.json").read_text())
    print("\n| stage | epoch | lr | train loss | val mIoU | val offset L1 (m) | val shift L1 | seconds |")
    print("|---|---|---|---|---|---|---|---|")
    for m in card["metrics"]:
        cells = [m.get(k) for k in ("lr", "train_loss", "val_miou", "val_offset_l1", "val_shift_l1")]
        text = " | ".join("" if v is None else f"{v:.4g}" for v in cells)
        print(f"| {m['stage']} | {m['epoch']} | {text} | {m.get('seconds', '')} |")
    done = card["epochs"]
    files = sorted(out.iterdir())
    total = sum(f.stat().st_size for f in files)
    print(f"\n{len(files)} files, {total / 2**20:.1f} MiB in {out}: " + ", ".join(f.name for f in files))
    left = {s: n - done.get(s, 0) for s, n in planned.items() if n > done.get(s, 0)}
    if stopped:
        print(stopped)
    print(
        f"epochs done {done}; " + (f"left {left}: run again with OUT={out} to resume" if left else "finished")
    )
    print(f"({time.perf_counter() - START:.0f} s)")


if __name__ == "__main__":
    main()
