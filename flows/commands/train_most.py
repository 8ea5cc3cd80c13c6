"""``dsnet train --method most``: MOST's two training stages (detect, then PointSegMLP), resumable."""

from __future__ import annotations

from pathlib import Path

import typer

from flows.commands.common import fail, with_grid

MOST_STAGES = ("detect", "member")


def parse_most_epochs(text: str) -> dict[str, int]:
    """``"6"`` → 6 epochs for both stages; ``"detect=6,member=2"`` → per stage (unnamed ones 0)."""
    if "=" not in text:
        n = int(text)
        return dict.fromkeys(MOST_STAGES, n)
    out = dict.fromkeys(MOST_STAGES, 0)
    for part in text.split(","):
        name, _, value = part.partition("=")
        if name.strip() not in out:
            raise typer.BadParameter(f"unknown MOST stage '{name}' in --epochs (stages: detect, member)")
        out[name.strip()] = int(value)
    return out


def train_most(
    data: Path,
    out: Path,
    stage: str,
    scans: int | None,
    epochs: str,
    device: str,
    resume: bool,
    init_from: Path | None,
    preset: str,
    grid: str | None,
    sequences: str | None,
    val_data: Path | None,
    val_sequences: str | None,
    lr: float,
    seed: int,
    augment: bool,
    threads: int,
    refused: dict[str, bool],
) -> None:
    """Run :class:`dsnet_core.train.most.MostTrainer` for the command line's settings.

    ``refused``: DS-Net-only flags and whether each was given (an error names them).
    """
    import logging

    import torch

    from dsnet_core.errors import DsnetError
    from dsnet_core.io.formats import open_log
    from dsnet_core.labels import load_label_map
    from dsnet_core.model.presets import get_preset
    from dsnet_core.most.config import DEFAULT_SCANS, MostConfig
    from dsnet_core.train.most import MostTrainConfig, MostTrainer

    bad = [flag for flag, given in refused.items() if given]
    if bad:
        fail(f"{', '.join(bad)}: not a setting of dsnet train --method most (they apply to --method dsnet)")
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(message)s")
    torch.set_num_threads(threads)
    try:
        label_map = load_label_map("semantic-kitti")
        reader = open_log(data, options={"label_map": label_map})
        seqs = sequences.split(",") if sequences else reader.sequences()
        val_reader = open_log(val_data, options={"label_map": label_map}) if val_data else reader
        vseqs = val_sequences.split(",") if val_sequences else (val_reader.sequences() if val_data else seqs)
        cfg = MostTrainConfig(
            stage=stage,
            epochs=parse_most_epochs(epochs),
            lr=lr,
            scans=scans or DEFAULT_SCANS,
            seed=seed,
            augment=augment,
            device=device,
        )
        cfg.stages()  # an unknown --stage fails before any data is read
        config = MostConfig(backbone=with_grid(get_preset(preset), grid))
        trainer = MostTrainer(
            out, config, reader, seqs, val_reader, vseqs, label_map, cfg, resume, backbone_from=init_from
        )
        card = trainer.run()
    except DsnetError as exc:
        fail(exc)
    last = card.metrics[-1] if card.metrics else {}
    miou, recall = last.get("val_miou", float("nan")), last.get("val_det_recall", float("nan"))
    typer.echo(
        f"wrote MOST checkpoint {out.resolve()} (epochs {card.epochs}, val mIoU {miou:.4f}, "
        f"detection recall {recall:.3f})"
    )
    typer.echo(f"metrics table: {out.resolve() / 'metrics.csv'}")
