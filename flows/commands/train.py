"""``dsnet train``: train the network on a labelled log (staged, resumable)."""

from __future__ import annotations

from pathlib import Path

import typer

from flows.commands.common import fail


def parse_epochs(text: str) -> dict[str, int]:
    """``"10"`` → 10 epochs for every stage; ``"semantic=10,offset=5"`` → per stage."""
    if "=" not in text:
        n = int(text)
        return {"semantic": n, "offset": n, "shift": n}
    out = {"semantic": 0, "offset": 0, "shift": 0}
    for part in text.split(","):
        name, _, value = part.partition("=")
        if name.strip() not in out:
            raise typer.BadParameter(f"unknown stage '{name}' in --epochs")
        out[name.strip()] = int(value)
    return out


def train(
    data: Path = typer.Argument(..., help="Training log root (SemanticKITTI layout)."),
    out: Path = typer.Option(..., "--out", help="Checkpoint folder (written every epoch)."),
    stage: str = typer.Option("all", help="semantic | offset | shift | all"),
    scans: int = typer.Option(1, help="Scans per 4D volume (1 = single scan)."),
    epochs: str = typer.Option("10", help="Epochs per stage: N, or e.g. 'semantic=20,offset=5'."),
    device: str = typer.Option("cpu", help="cpu | cuda"),
    resume: bool = typer.Option(False, "--resume", help="Continue the checkpoint in --out."),
    init_from: Path = typer.Option(
        None,
        "--init-from",
        help="Fine-tune: start --out from this checkpoint's weights and architecture (e.g. a 3D model "
        "fine-tuned on --scans 2 volumes with --epochs semantic=0,offset=2,shift=2).",
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
        help="Eq-4D: a C_n yaw-equivariant network (n must divide the azimuth cells).",
    ),
    pooling: str = typer.Option("mean", "--pooling", help="Equivariant: invariant pooling, mean or max."),
    method: str = typer.Option(
        "dsnet",
        "--method",
        help="dsnet (the staged DS-Net network) or dpls (D-PLS's prior-conditioned instance network, "
        "started from --init-from, default the bundled model, trained on realistically corrupted "
        "ground-truth priors; --epochs N).",
    ),
) -> None:
    """Train DS-Net (semantic → instance head → shifting) and write a checkpoint with a model card."""
    if method == "dpls":
        _train_dpls(data, out, epochs, device, resume, init_from, sequences, val_data, val_sequences, lr,
                    scans, seed, augment, threads)  # fmt: skip
        return
    if method != "dsnet":
        raise typer.BadParameter(f"--method must be dsnet or dpls, not {method!r}")
    import logging
    from dataclasses import replace

    import torch
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from dsnet_core.errors import DsnetError
    from dsnet_core.io.formats import open_log
    from dsnet_core.labels import load_label_map
    from dsnet_core.model.presets import get_preset
    from dsnet_core.train.loop import TrainConfig, Trainer

    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(message)s")
    torch.set_num_threads(threads)
    console = Console(stderr=True)
    try:
        label_map = load_label_map("semantic-kitti")
        reader = open_log(data, options={"label_map": label_map})
        seqs = sequences.split(",") if sequences else reader.sequences()
        val_reader = open_log(val_data, options={"label_map": label_map}) if val_data else reader
        if val_sequences:
            vseqs = val_sequences.split(",")
        else:
            vseqs = val_reader.sequences() if val_data else seqs
        if not val_data and not val_sequences and not holdout:
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
        model_config = get_preset(preset)
        if grid:
            cells = tuple(int(v) for v in grid.split(",") if v.strip().isdigit())
            if len(cells) != 3:
                raise typer.BadParameter(f"--grid wants three cell counts 'ρ,φ,z', got '{grid}'")
            model_config = replace(model_config, grid=replace(model_config.grid, size=cells))
        if equivariant != 1 or pooling != "mean":
            model_config = replace(model_config, equivariant=equivariant, pooling=pooling)
        trainer = Trainer(
            out, model_config, reader, seqs, val_reader, vseqs, label_map, cfg, resume, init_from
        )
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
