"""``dsnet train``: train the network on a labelled log (staged, resumable).

Under ``torchrun --nproc_per_node N -m flows.cli train …`` it trains data-parallel, one process per
GPU; rank 0 alone shows progress, logs at INFO and writes the checkpoint.
"""

from __future__ import annotations

from pathlib import Path

import typer

from flows.commands.common import fail, with_grid


def parse_epochs(text: str) -> dict[str, int]:
    """``"10"`` → 10 epochs for the semantic, offset and shift stages (joint only when named);
    ``"semantic=10,offset=5"`` or ``"joint=2,shift=1"`` → per stage, unnamed stages 0."""
    if "=" not in text:
        n = int(text)
        return {"semantic": n, "offset": n, "joint": 0, "shift": n}
    out = {"semantic": 0, "offset": 0, "joint": 0, "shift": 0}
    for part in text.split(","):
        name, _, value = part.partition("=")
        if name.strip() not in out:
            raise typer.BadParameter(f"unknown stage '{name}' in --epochs")
        out[name.strip()] = int(value)
    return out


def stream_log(seed: int, scans: int, samples: int, styles: str | None, sensors: str | None, workers: int):
    """The :class:`~dsnet_core.train.stream.StreamLog` of ``--stream`` (samples of k = ``scans`` frames)."""
    from dsnet_core.synth.stream import StreamOptions
    from dsnet_core.train.stream import StreamLog

    def names(text: str | None) -> tuple[str, ...] | None:
        return tuple(v.strip() for v in text.split(",") if v.strip()) if text else None

    options = StreamOptions(frames=scans, styles=names(styles), sensors=names(sensors))
    return StreamLog(seed, options, samples, workers)


def train(
    data: Path = typer.Argument(None, help="Training log root (SemanticKITTI layout); none with --stream."),
    out: Path = typer.Option(..., "--out", help="Checkpoint folder (written every epoch)."),
    method: str = typer.Option(
        "dsnet",
        "--method",
        help="dsnet (DS-Net / 4D-DS-Net), most (detect → member stages) or dpls (D-PLS's prior-conditioned "
        "instance network from --init-from, default the bundled model, on corrupted ground-truth priors).",
    ),
    stage: str = typer.Option(
        "all", help="semantic | offset | joint | shift | all (most: detect | member | all)"
    ),
    scans: int = typer.Option(
        None,
        help="Scans per 4D volume (default 1 = single scan); most: current + k-1 past scans (default 3).",
    ),
    epochs: str = typer.Option(
        "10",
        help="Epochs per stage: N, or e.g. 'semantic=20,offset=5'; 'joint=N' trains backbone, semantic "
        "and instance heads together (4D-DS-Net's fine-tune on --scans k volumes, after --init-from).",
    ),
    device: str = typer.Option("cpu", help="cpu | cuda"),
    resume: bool = typer.Option(False, "--resume", help="Continue the checkpoint in --out."),
    init_from: Path = typer.Option(
        None,
        "--init-from",
        help="Fine-tune: start --out from this checkpoint's weights and architecture (e.g. a 3D model "
        "fine-tuned on --scans 2 volumes with --epochs semantic=0,offset=2,shift=2); most: a DS-Net "
        "checkpoint whose backbone and semantic head start the MOST network.",
    ),
    preset: str = typer.Option(
        "tiny", help="Model preset: tiny | small | paper | reference | cylinder3d (the released shapes)."
    ),
    sequences: str = typer.Option(None, help="Comma-separated training sequences (default: all)."),
    val_data: Path = typer.Option(None, help="Validation log root (default: DATA)."),
    val_sequences: str = typer.Option(None, help="Validation sequences (default: the training ones)."),
    lr: float = typer.Option(1e-3, help="Adam learning rate (the start of each stage's schedule)."),
    schedule: str = typer.Option("cosine", help="Learning-rate schedule per stage: cosine | constant."),
    batch_size: int = typer.Option(1, help="Volumes per step."),
    seed: int = typer.Option(0, help="Seed of initialisation, shuffling and augmentation."),
    augment: bool = typer.Option(True, help="Yaw/flip/scale/translation augmentation."),
    threads: int = typer.Option(1, help="Torch CPU threads."),
    grid: str = typer.Option(None, help="Cylinder cells 'ρ,φ,z' (default: the preset's, 480,360,32)."),
    freeze_backbone: bool = typer.Option(
        False,
        "--freeze-backbone/--train-all",
        help="Fine-tuning: the semantic stage trains only the semantic head (default: everything).",
    ),
    holdout: float = typer.Option(
        0.0, help="Hold back this fraction of the training frames for validation (e.g. 0.2 for a few frames)."
    ),
    patience: int = typer.Option(
        0, help="Early stop: end a stage after N epochs without a better validation score, keep the best."
    ),
    amp: str = typer.Option(
        "off", "--amp", help="Mixed precision: off, bf16 (CPU or CUDA) or fp16 (CUDA, gradient scaler)."
    ),
    equivariant: int = typer.Option(
        1,
        "--equivariant",
        min=1,
        help="Eq-4D: a C_n yaw-equivariant network (n must divide the azimuth cells); with --init-from a "
        "plain model, its weights lifted to C_n (shared by the n rotated copies) and fine-tuned.",
    ),
    pooling: str = typer.Option("mean", "--pooling", help="Equivariant: invariant pooling, mean or max."),
    stream: int = typer.Option(
        0,
        "--stream",
        min=0,
        help="Train on N never-seen generated sequences per epoch instead of DATA (needs --val-data).",
    ),
    stream_styles: str = typer.Option(None, help="--stream: street styles to draw from (default: all)."),
    stream_sensors: str = typer.Option(None, help="--stream: sensors to draw from (default: all)."),
    stream_workers: int = typer.Option(1, min=0, help="--stream: background render processes."),
) -> None:
    """Train DS-Net (semantic → instance head → shifting), MOST (``--method most``: detection,
    segmentation and velocity → PointSegMLP) or D-PLS's instance network (``--method dpls``) and
    write a checkpoint with a model card.

    DS-Net trains data-parallel under torchrun: ``torchrun --nproc_per_node 2 -m flows.cli train DATA
    --out CKPT --device cuda`` (``--batch-size`` is per process)."""
    if method not in ("dsnet", "most", "dpls"):
        raise typer.BadParameter(f"--method must be dsnet, most or dpls, not {method!r}")
    if (data is None) == (stream == 0):
        fail("give a training log (DATA) or --stream N, not both or neither")
    if stream and (val_data is None or holdout):
        fail("--stream needs --val-data VAL (a folder log: the stream has no fixed frames to hold out)")
    if method == "most":
        import os

        from flows.commands.train_most import train_most

        if int(os.environ.get("WORLD_SIZE", "1")) > 1:  # every process would write the checkpoint
            fail("--method most trains in one process: run it without torchrun (or --nproc_per_node 1)")
        refused = {
            "--freeze-backbone": freeze_backbone,
            "--holdout": holdout != 0.0,
            "--patience": patience != 0,
            "--amp": amp != "off",
            "--equivariant": equivariant != 1,
            "--pooling": pooling != "mean",
            "--batch-size": batch_size != 1,
            "--schedule": schedule != "cosine",
        }
        return train_most(
            data, out, stage, scans, epochs, device, resume, init_from, preset, grid, sequences, val_data,
            val_sequences, lr, seed, augment, threads, refused,
        )  # fmt: skip
    if method == "dpls":
        import os

        if int(os.environ.get("WORLD_SIZE", "1")) > 1:  # every process would write the checkpoint
            fail("--method dpls trains in one process: run it without torchrun (or --nproc_per_node 1)")
        refused = {
            "--stream": stream != 0,
            "--stage": stage != "all",
            "--freeze-backbone": freeze_backbone,
            "--holdout": holdout != 0.0,
            "--patience": patience != 0,
            "--amp": amp != "off",
            "--equivariant": equivariant != 1,
            "--batch-size": batch_size != 1,
            "--grid": grid is not None,
        }
        bad = [flag for flag, given in refused.items() if given]
        if bad:
            fail(f"{', '.join(bad)}: not a setting of dsnet train --method dpls")
        _train_dpls(data, out, epochs, device, resume, init_from, sequences, val_data, val_sequences, lr,
                    scans, seed, augment, threads)  # fmt: skip
        return
    scans = scans or 1
    import logging
    from dataclasses import replace

    import torch
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from dsnet_core.errors import DsnetError
    from dsnet_core.io.formats import open_log
    from dsnet_core.labels import load_label_map
    from dsnet_core.model.presets import get_preset
    from dsnet_core.train import distributed
    from dsnet_core.train.loop import TrainConfig, Trainer

    torch.set_num_threads(threads)
    dist, _ = distributed.setup(device)  # one process without torchrun
    level = logging.INFO if dist.is_main else logging.WARNING
    rank = f" rank {dist.rank}" if dist.active else ""
    logging.basicConfig(level=level, format=f"%(asctime)s{rank} %(levelname)s %(message)s")
    console = Console(stderr=True)
    try:
        label_map = load_label_map("semantic-kitti")
        if stream:
            reader = stream_log(seed, scans, stream, stream_styles, stream_sensors, stream_workers)
            seqs = reader.probe()  # the class statistics the loss weights come from
        else:
            reader = open_log(data, options={"label_map": label_map})
            seqs = sequences.split(",") if sequences else reader.sequences()
        val_reader = open_log(val_data, options={"label_map": label_map}) if val_data else reader
        if val_sequences:
            vseqs = val_sequences.split(",")
        else:
            vseqs = val_reader.sequences() if val_data else seqs
        if not val_data and not val_sequences and not holdout and dist.is_main:
            console.print("[yellow]no validation set given: validating on the training sequences[/]")
        cfg = TrainConfig(
            stage=stage,
            epochs=parse_epochs(epochs),
            lr=lr,
            schedule=schedule,
            scans=scans,
            batch_size=batch_size,
            seed=seed,
            augment=augment,
            device=device,
            freeze_backbone=freeze_backbone,
            holdout=holdout,
            patience=patience,
            amp=amp,
        )
        model_config = with_grid(get_preset(preset), grid)
        if equivariant != 1 or pooling != "mean":
            model_config = replace(model_config, equivariant=equivariant, pooling=pooling)
        lift = (equivariant, pooling) if init_from is not None and equivariant != 1 else None
        trainer = Trainer(
            out, model_config, reader, seqs, val_reader, vseqs, label_map, cfg, resume, init_from, lift
        )
        if not dist.is_main:  # progress and the final lines come from rank 0
            trainer.run()
            return
        with Progress(
            TextColumn("{task.description}"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn("loss {task.fields[loss]:.4f}"),
            TimeElapsedColumn(),
            console=console,
        ) as bar:
            tasks: dict = {}

            def on_step(stage_name: str, epoch: int, step: int, total: int, loss: float) -> None:
                key = (stage_name, epoch)
                if key not in tasks:
                    tasks[key] = bar.add_task(f"{stage_name} epoch {epoch}", total=total, loss=loss)
                bar.update(tasks[key], completed=step, loss=loss)

            card = trainer.run(on_step=on_step)
    except DsnetError as exc:
        fail(exc)
    finally:
        if stream and "reader" in locals():
            reader.close()
        distributed.teardown()
    miou = card.metrics[-1]["val_miou"] if card.metrics else float("nan")
    typer.echo(f"wrote checkpoint {out.resolve()} (epochs {card.epochs}, val mIoU {miou:.4f})")
    typer.echo(f"metrics table: {out.resolve() / 'metrics.csv'}")


def _train_dpls(data, out, epochs, device, resume, init_from, sequences, val_data, val_sequences, lr,
                scans, seed, augment, threads) -> None:  # fmt: skip
    """``dsnet train --method dpls`` (:class:`dsnet_core.train.dpls.DplsTrainer`)."""
    import logging

    import torch

    from dsnet_core.errors import DsnetError
    from dsnet_core.io.formats import open_log
    from dsnet_core.labels import load_label_map
    from dsnet_core.model.bundle import bundled_checkpoint
    from dsnet_core.train.dpls import DplsTrainConfig, DplsTrainer

    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(message)s")
    torch.set_num_threads(threads)
    if "=" in epochs:
        raise typer.BadParameter("--method dpls trains one stage: --epochs N")
    try:
        label_map = load_label_map("semantic-kitti")
        reader = open_log(data, options={"label_map": label_map})
        seqs = sequences.split(",") if sequences else reader.sequences()
        val_reader = open_log(val_data, options={"label_map": label_map}) if val_data else reader
        vseqs = val_sequences.split(",") if val_sequences else (val_reader.sequences() if val_data else seqs)
        cfg = DplsTrainConfig(
            epochs=int(epochs), lr=lr, scans=scans, seed=seed, augment=augment, device=device
        )
        start = init_from or bundled_checkpoint(1)
        trainer = DplsTrainer(out, reader, seqs, val_reader, vseqs, label_map, cfg, start, resume)
        card = trainer.run()
    except DsnetError as exc:
        fail(exc)
    last = card.metrics[-1] if card.metrics else {}
    typer.echo(
        f"wrote checkpoint {out.resolve()} (epochs {card.epochs}, val offset L1 clean "
        f"{last.get('val_offset_l1_clean', float('nan')):.3f} m, corrupted prior "
        f"{last.get('val_offset_l1_corrupted', float('nan')):.3f} m)"
    )
