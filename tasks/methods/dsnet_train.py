"""``dsnet train dsnet``: options → :class:`~dsnet_core.train.loop.Trainer` → the trained card.

Under torchrun (``WORLD_SIZE`` > 1) the trainer joins the process group and trains data-parallel;
rank 0 alone reports progress and the result.
"""

from __future__ import annotations

import logging
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Literal

from pydantic import Field

from tasks.methods.base import StepCallback
from tasks.methods.training import StepOptions, open_training_data

if TYPE_CHECKING:
    from tasks.methods.base import Method

log = logging.getLogger(__name__)
TRAIN_STAGES = ("semantic", "offset", "joint", "shift")
PLAIN_STAGES = ("semantic", "offset", "shift")
"""What ``--epochs N`` trains: every stage but ``joint`` (4D-DS-Net's fine-tune, named to run)."""


class DsnetTrainOptions(StepOptions):
    """Semantic stage, instance head, shifting MLPs (and 4D-DS-Net's joint fine-tune on k-scan
    volumes); data-parallel under torchrun."""

    epochs: str = Field(
        "10",
        description="Epochs per stage: N (semantic, offset, shift), or e.g. 'semantic=20,offset=5'; "
        "'joint=N' trains backbone and both heads together (4D-DS-Net's fine-tune, after --init-from).",
    )
    stage: Literal["semantic", "offset", "joint", "shift", "all"] = Field(
        "all", description="semantic | offset | joint | shift | all."
    )
    scans: int = Field(1, ge=1, le=16, description="Scans per 4D volume (1 = single scans).")
    preset: str = Field("tiny", description="Model preset: tiny | small | paper | reference | cylinder3d.")
    width: int | None = Field(
        None, ge=1, description="U-Net base width (default: the preset's: tiny 4, small 8, paper 32)."
    )
    grid: str | None = Field(None, description="Cylinder cells 'ρ,φ,z' (default: the preset's).")
    freeze_backbone: bool = Field(False, description="The semantic stage trains only the semantic head.")
    holdout: float = Field(0.0, ge=0.0, lt=1.0, description="Fraction of frames held back to validate.")
    patience: int = Field(0, ge=0, description="Early stop after N epochs without a better score.")
    equivariant: int = Field(1, ge=1, description="Eq-4D: a C_n yaw-equivariant network (n divides φ cells).")
    pooling: Literal["mean", "max"] = Field("mean", description="Equivariant: invariant pooling.")
    inputs: str = Field(
        "xyz,remission",
        description="Input channels: xyz, plus remission (raw) or remission-rank (per-scan quantiles), "
        "plus height (above the fitted ground); e.g. 'xyz,remission-rank,height'. 'xyz' alone: no remission.",
    )
    remission_dropout: float = Field(
        0.0, ge=0.0, lt=1.0, description="Training: probability a scan's remission is replaced by a constant."
    )
    stream: int = Field(0, ge=0, description="Train on N never-seen generated sequences per epoch.")
    stream_styles: str | None = Field(None, description="--stream: street styles (default: all).")
    stream_sensors: str | None = Field(None, description="--stream: sensors (default: all).")
    stream_workers: int = Field(1, ge=0, description="--stream: background render processes.")
    stream_like: str | None = Field(
        None, description="--stream: render with the LiDAR estimated from this log (dsnet describe --sensor)."
    )
    stream_variety: Literal["base", "wide"] = Field(
        "base", description="--stream: the street styles' variety, base or wide."
    )
    real: Path | None = Field(
        None, description="Mix real labelled scans of this log into training (docs/realdata.md)."
    )
    real_sequences: str | None = Field(
        None, description="--real: the sequences to train on, named (required; e.g. 30 for PandaSet)."
    )
    real_share: float = Field(0.5, gt=0.0, le=1.0, description="--real: share of samples with a real scan.")
    real_mix: Literal["both", "laser", "polar", "none"] = Field(
        "both", description="--real: LaserMix bands, PolarMix sectors, both (drawn per sample) or none."
    )
    real_attribution: str | None = Field(
        None,
        description="--real: the data's attribution, recorded in the card (PandaSet: its CC BY 4.0 line).",
    )


def model_config(options: DsnetTrainOptions):
    """The architecture of a new checkpoint: the preset, its ``--width``, ``--grid`` cells,
    equivariance, the input channels and remission dropout (:mod:`dsnet_core.model.inputs`).

    Raises:
        ValueError: an unknown preset, or a grid that is not three cell counts ≥ 1.
        ConfigError: an unknown input channel.
    """
    from dsnet_core.model.presets import get_preset

    config = get_preset(options.preset)
    if options.width is not None and options.width != config.width:
        config = replace(config, width=options.width)
    if options.grid:
        config = replace(config, grid=replace(config.grid, size=parse_grid(options.grid)))
    if options.equivariant != 1 or options.pooling != "mean":
        config = replace(config, equivariant=options.equivariant, pooling=options.pooling)
    if options.inputs != config.inputs or options.remission_dropout:
        config = replace(config, inputs=options.inputs, remission_dropout=options.remission_dropout)
    return config


def _check_inherited_inputs(options: DsnetTrainOptions, init_from) -> None:
    """A fine-tune keeps its parent's inputs and width: refuse ``--inputs``/``--remission-dropout``/
    ``--width`` given explicitly with other values than the ``--init-from`` model's card.

    Raises:
        ConfigError: naming both.
    """
    from dsnet_core.errors import ConfigError
    from dsnet_core.model.checkpoint import read_card
    from dsnet_core.model.inputs import InputSpec

    given = options.model_fields_set & {"inputs", "remission_dropout", "width"}
    if not given:
        return
    parent = read_card(init_from).config
    if options.width is not None and options.width != parent.width:  # None: the command line's default
        raise ConfigError(
            f"--width {options.width}: the --init-from model {init_from} has width {parent.width}; "
            "a fine-tune keeps its parent's architecture"
        )
    if "inputs" in given and str(InputSpec.parse(options.inputs)) != parent.inputs:
        raise ConfigError(
            f"--inputs {options.inputs}: the --init-from model {init_from} was trained with inputs "
            f"{parent.inputs}; a fine-tune keeps its parent's inputs"
        )
    if "remission_dropout" in given and options.remission_dropout != parent.remission_dropout:
        raise ConfigError(
            f"--remission-dropout {options.remission_dropout}: the --init-from model {init_from} has "
            f"{parent.remission_dropout}; a fine-tune keeps its parent's"
        )


def parse_grid(text: str) -> tuple[int, int, int]:
    """``'480,360,32'`` → cells (ρ, φ, z). Raises ValueError unless three whole numbers ≥ 1."""
    parts = [v.strip() for v in text.split(",")]
    if len(parts) != 3 or not all(p.isdigit() and int(p) >= 1 for p in parts):
        raise ValueError(f"--grid wants three cell counts ≥ 1 'ρ,φ,z', got {text!r}")
    return tuple(int(p) for p in parts)  # type: ignore[return-value]


def stream_reader(options: DsnetTrainOptions):
    """The :class:`~dsnet_core.train.stream.StreamLog` of ``--stream`` (samples of k = ``scans``)."""
    from dsnet_core.synth.config import SynthConfig
    from dsnet_core.synth.stream import StreamOptions
    from dsnet_core.train.stream import StreamLog

    styles, sensors = options.names(options.stream_styles), options.names(options.stream_sensors)
    stream = StreamOptions(
        frames=options.scans,
        styles=tuple(styles) if styles else None,
        sensors=tuple(sensors) if sensors else None,
        config=SynthConfig(variety=options.stream_variety),
        card=_stream_card(options.stream_like),
    )
    return StreamLog(options.seed, stream, options.stream, options.stream_workers)


def _stream_card(log: str | None):
    """The sensor card estimated from ``log`` (None: no log)."""
    if not log:
        return None
    from dsnet_core.io.formats import open_log
    from dsnet_core.sensor import estimate_sensor

    return estimate_sensor(open_log(log), log).card


def real_data(options: DsnetTrainOptions, label_map, val_sequences: list[str]):
    """The :class:`~dsnet_core.train.real.RealData` of ``--real`` (None without it).

    Raises:
        ConfigError: ``--real-sequences`` missing, or naming a sequence the run validates on.
    """
    from dsnet_core.errors import ConfigError
    from dsnet_core.io.formats import open_log
    from dsnet_core.train.real import RealData, RealOptions

    if options.real is None:
        if options.real_sequences or options.real_attribution:
            raise ConfigError("--real-sequences and --real-attribution need --real DIR")
        return None
    sequences = options.names(options.real_sequences)
    if not sequences:
        raise ConfigError(
            f"--real {options.real}: name the sequences to train on with --real-sequences (e.g. 30 for "
            "PandaSet, whose 31 and 32 are validation only)"
        )
    if options.val_data is not None and Path(options.val_data).resolve() == Path(options.real).resolve():
        both = sorted(set(sequences) & set(val_sequences))
        if both:
            raise ConfigError(
                f"--real-sequences {','.join(both)} are also validation sequences of {options.real}"
            )
    if not options.real_attribution:
        log.warning("--real %s: no --real-attribution: the card carries none", options.real)
    reader = open_log(options.real)
    opts = RealOptions(
        Path(options.real), tuple(sequences), options.real_share, options.real_mix, options.real_attribution
    )
    return RealData(reader, opts, options.scans, label_map)


def train_dsnet(method: Method, options: DsnetTrainOptions, on_step: StepCallback | None = None) -> str:
    """Train (or resume) a checkpoint of ``method`` (DS-Net; ``--init-from bundled`` is its bundled
    model for k = ``scans``); returns the summary line.

    Raises:
        ConfigError: bad data or settings (e.g. neither or both of DATA and ``--stream``).
    """
    from dsnet_core.errors import ConfigError

    # the options first, before torch and the trainer are imported (seconds on a loaded machine)
    if (options.data is None) == (options.stream == 0):
        raise ConfigError("give a training log (DATA) or --stream N, not both or neither")
    if options.stream and (options.val_data is None or options.holdout):
        raise ConfigError("--stream needs --val-data VAL (the stream has no fixed frames to hold out)")
    epochs = options.epoch_counts(TRAIN_STAGES, PLAIN_STAGES)
    if options.stage != "all" and not epochs[options.stage]:
        raise ConfigError(
            f"--stage {options.stage} with --epochs {options.epochs!r} trains 0 epochs: name it (e.g. "
            f"--epochs {options.stage}=2)"
        )
    config = model_config(options)

    import torch

    from dsnet_core.train import distributed
    from dsnet_core.train.loop import TrainConfig, Trainer
    from dsnet_core.train.skeleton import config_from

    torch.set_num_threads(options.threads)
    stream = stream_reader(options) if options.stream else None
    try:
        if stream is not None:
            stream.probe()  # the class statistics the loss weights come from
        data = open_training_data(options, stream)
        if data.validates_on_training and not options.holdout:
            log.warning("no validation set given: validating on the training sequences")
        cfg = config_from(TrainConfig, options.model_dump(), epochs=epochs)
        init_from = options.start_from(method, options.scans)
        if init_from is not None:
            _check_inherited_inputs(options, init_from)
        lift = (options.equivariant, options.pooling) if init_from and options.equivariant != 1 else None
        real = real_data(options, data.label_map, data.val_sequences)
        trainer = Trainer(
            options.out, config, data.reader, data.sequences, data.val_reader, data.val_sequences,
            data.label_map, cfg, options.resume, init_from, lift, real,
        )  # fmt: skip
        card = trainer.run(on_step=on_step if trainer.dist.is_main else None)
    finally:
        if stream is not None:
            stream.close()
        distributed.teardown()
    miou = card.metrics[-1]["val_miou"] if card.metrics else float("nan")
    return f"wrote checkpoint {options.out.resolve()} (epochs {card.epochs}, val mIoU {miou:.4f})"
