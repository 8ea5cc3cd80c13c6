"""What every method's trainer does alike before it trains: the options of the trainer skeleton's
step loop (:class:`StepOptions`), and the training and validation logs with the label map of the
training data's reader (never a hard-coded dataset)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal

from pydantic import Field

from tasks.methods.base import TrainOptions

if TYPE_CHECKING:
    from dsnet_core.io.reader import LogReader
    from dsnet_core.labels import LabelMap


class StepOptions(TrainOptions):
    """The options of the skeleton's step loop (:class:`~dsnet_core.train.skeleton.StepConfig`),
    the same for every trainer on it; each becomes the config field of its name
    (:func:`~dsnet_core.train.skeleton.config_from`)."""

    schedule: Literal["cosine", "constant"] = Field("cosine", description="Learning rate per stage.")
    batch_size: int = Field(1, ge=1, description="Volumes per step (per process under torchrun).")
    amp: Literal["off", "bf16", "fp16"] = Field("off", description="Mixed precision: off, bf16 or fp16.")
    grad_clip: float = Field(0.0, ge=0.0, description="Clip each step's gradient norm to this (0: off).")


@dataclass
class TrainingData:
    """The logs a trainer reads.

    Attributes:
        reader, sequences: training data.
        val_reader, val_sequences: validation data (the training log when none is given).
        label_map: the training log's label map (its reader's).
        validates_on_training: no validation data was given.
    """

    reader: LogReader
    sequences: list[str]
    val_reader: LogReader
    val_sequences: list[str]
    label_map: LabelMap
    validates_on_training: bool


def open_training_data(options: TrainOptions, reader: LogReader | None = None) -> TrainingData:
    """Open ``options.data`` (or use ``reader``, e.g. a synthetic stream) and the validation log.

    Raises:
        ConfigError: no training data, or a log without ground-truth labels.
        DataFormatError: the log does not read.
    """
    from dsnet_core.errors import ConfigError
    from dsnet_core.io.formats import open_log

    if reader is None:
        if options.data is None:
            raise ConfigError("give a training log (DATA)")
        reader = open_log(options.data)
    label_map = reader.label_map
    if label_map is None:
        raise ConfigError(f"{options.data}: the log has no ground-truth labels to train on")
    seqs = options.names(options.sequences) or reader.sequences()
    val_reader = open_log(options.val_data) if options.val_data else reader
    if (
        options.val_data
        and val_reader.label_map is not None
        and (val_reader.label_map.num_classes != label_map.num_classes)
    ):
        raise ConfigError(
            f"{options.val_data}: its label map has {val_reader.label_map.num_classes} classes, the "
            f"training log's {label_map.num_classes}"
        )
    vseqs = options.names(options.val_sequences) or (val_reader.sequences() if options.val_data else seqs)
    given = options.val_data is not None or options.val_sequences is not None
    return TrainingData(reader, seqs, val_reader, vseqs, label_map, not given)
