"""``dsnet adapt``: self-train a method's network on unlabelled target logs (``docs/adapt.md``).

:class:`AdaptOptions` (each field a command-line option) → the target logs, the corrected frames,
the source scans and the teacher (:class:`~tasks.adapt_teacher.TeacherLabeller`) →
:class:`~dsnet_core.adapt.trainer.AdaptTrainer`. Everything the run writes lives under ``--out``:
the checkpoint (the EMA teacher), ``store/`` (one run store per target log), ``rounds/R/`` (each
round's teacher snapshot and pseudo-labels).
"""

from __future__ import annotations

import hashlib
import logging
import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationInfo, field_validator

from tasks.methods import DEFAULT_METHOD, LabelSettings, get_method
from tasks.methods.base import StepCallback, check_device

log = logging.getLogger(__name__)


class AdaptOptions(BaseModel):
    """Self-training on unlabelled target logs: teacher labels (with refine) → class-balanced
    pseudo-labels → a student trained on them mixed with source scans → an EMA teacher that relabels
    between rounds. ``--out`` is the adapted checkpoint (resumable; every epoch committed)."""

    model_config = ConfigDict(extra="forbid", populate_by_name=True)

    logs: list[Path] = Field(..., description="Unlabelled target logs (any format).")
    out: Path = Field(..., description="The adapted checkpoint (folder; also holds the run stores).")
    init_from: Path | None = Field(
        None, alias="from", description="Checkpoint to adapt (default: the bundled model for --scans)."
    )
    labels: Path | None = Field(
        None,
        description="Corrected frames: a `dsnet review export` folder, or DIR/sequences/SS/labels/ID.label.",
    )
    rounds: int = Field(2, ge=1, description="Label → select → train rounds.")
    steps: int = Field(200, ge=1, description="Student steps per round (one mixed scan each).")
    epochs: int = Field(2, ge=1, description="Epochs per round (a checkpoint each).")
    scans: int = Field(1, ge=1, le=16, description="Scans per 4D volume.")
    method: str = Field(DEFAULT_METHOD, description="The labelling method whose network adapts.")
    lr: float = Field(1e-3, gt=0, description="Adam learning rate (constant).")
    ema: float = Field(0.99, ge=0, lt=1, description="The teacher's EMA decay per student step.")
    keep: float = Field(0.5, gt=0, le=1, description="Each class's most confident share kept.")
    min_confidence: float = Field(0.3, ge=0, le=1, description="No class threshold below this.")
    max_confidence: float = Field(0.9, ge=0, le=1, description="No class threshold above this.")
    mix: Literal["both", "laser", "polar", "none"] = Field("both", description="Target/source mixing.")
    label_weight: float = Field(2.0, gt=0, description="Loss weight of corrected frames.")
    holdout: float = Field(0.3, ge=0, lt=1, description="Share of corrected frames held back to validate.")
    patience: int = Field(2, ge=0, description="Held-out early stop (needs ≥ 3 held-back frames).")
    source_log: Path | None = Field(None, description="Labelled source log (default: the synthetic stream).")
    source_styles: str | None = Field(None, description="Stream styles (default: the parent's).")
    source_sensors: str | None = Field(None, description="Stream sensors (default: the parent's).")
    like: Path | None = Field(
        None,
        description="Render the synthetic source stream with the LiDAR estimated from this log "
        "(dsnet describe --sensor; e.g. the target log itself).",
    )
    sensor_card: Path | None = Field(
        None, description="Render the synthetic source stream with this sensor card (YAML, docs/sensor.md)."
    )
    stream_workers: int = Field(1, ge=0, description="Background render processes of the stream.")
    clusterer: str | None = Field(None, description="The teacher's clusterer (see dsnet label).")
    estimate_poses: bool = Field(False, description="Logs without poses: the teacher estimates them.")
    device: str = Field("cpu", description="cpu, cuda or cuda:N.")
    seed: int = Field(0, ge=0, description="Seed of order, augmentation, mixing and source samples.")
    threads: int = Field(1, ge=1, description="Torch CPU threads.")
    augment: bool = Field(True, description="Yaw/flip/scale/translation augmentation.")
    resume: bool = Field(False, description="Continue the checkpoint in --out.")

    @field_validator("device")
    @classmethod
    def valid_device(cls, value: str) -> str:
        return check_device(value) or "cpu"

    @field_validator("epochs")
    @classmethod
    def steps_cover_epochs(cls, value: int, info: ValidationInfo) -> int:
        """Refused here, before torch is imported (``AdaptConfig`` checks it again)."""
        steps = info.data.get("steps")
        if steps is not None and steps < value:
            raise ValueError(
                f"adapt needs steps ≥ epochs (a student step per epoch at least), got --steps {steps}"
            )
        return value

    def names(self, text: str | None) -> tuple[str, ...] | None:
        return tuple(v.strip() for v in text.split(",") if v.strip()) if text else None


def log_fingerprint(reader) -> str:
    """sha256 of a log's frames (sequence, frame id) and its scan files (names, sizes, first 64 KiB)."""
    h = hashlib.sha256()
    files = set()
    for seq in reader.sequences():
        for ref in reader.frames(seq):
            h.update(f"{seq}/{ref.frame_id};".encode())
            files.add(Path(ref.scan_path))
    for p in sorted(files):
        h.update(p.name.encode())
        if p.is_file():
            h.update(str(p.stat().st_size).encode())
            with open(p, "rb") as f:
                h.update(f.read(1 << 16))
    return h.hexdigest()


def run_adapt(options: AdaptOptions, on_step: StepCallback | None = None, on_label=None) -> str:
    """Adapt (or resume); returns the summary line.

    Raises:
        DsnetError, ValueError: bad logs, checkpoints or settings, each naming what is wrong.
    """
    from dsnet_core.io.formats import open_log
    from dsnet_core.model.card import read_card

    method = get_method(options.method)
    if not method.adaptable:
        raise ValueError(
            f"method {method.name} cannot be adapted (its network has no semantic head to self-train)"
        )
    if options.resume:  # an epoch a kill left committed but not moved: its card is the one to check
        from dsnet_core.model.card import CARD, check_card_files
        from dsnet_core.train import commit
        from tasks.methods.resume import refuse_lost_card

        commit.recover(options.out)
        if not (options.out / CARD).is_file():
            refuse_lost_card(options.out)
        else:  # before round R's teacher is copied from them (a copy's error would name the copy)
            check_card_files(options.out)
    parent = _parent(options, method)
    settings = LabelSettings(
        scans=options.scans,
        device=options.device,
        clusterer=options.clusterer,
        estimate_poses=options.estimate_poses,
    )
    # the teacher's options and the logs before torch and the sources are imported (seconds)
    _check_teacher_stages(method, settings, parent)
    reader_options: dict = {}  # adapt takes no reader options: the teacher records the same
    logs = [open_log(str(p), options=reader_options) for p in options.logs]
    if len({str(r.root) for r in logs}) < len(logs):
        raise ValueError("a target log is given twice")
    sensor = source_sensor(options)
    _check_resumed_logs(options, logs, method.name, sensor)

    import torch

    from dsnet_core.adapt import AdaptConfig, SelectionParams
    from dsnet_core.adapt.trainer import AdaptTrainer
    from dsnet_core.labels import label_map_from_class_map
    from tasks.adapt_sources import corrected_frames, source_scans
    from tasks.adapt_teacher import TeacherLabeller

    torch.set_num_threads(options.threads)
    card = read_card(parent)
    label_map = label_map_from_class_map(card.class_map)
    cfg = AdaptConfig(
        rounds=options.rounds,
        steps=options.steps,
        epochs=options.epochs,
        lr=options.lr,
        ema=options.ema,
        mix=options.mix,
        label_weight=options.label_weight,
        scans=options.scans,
        seed=options.seed,
        augment=options.augment,
        device=options.device,
        patience=options.patience,
    )
    params = SelectionParams(
        keep=options.keep, min_confidence=options.min_confidence, max_confidence=options.max_confidence
    )
    train, heldout, exclude = corrected_frames(options, logs, cfg)
    source, probe = source_scans(
        options, card, cfg, math.ceil(cfg.steps_in(0) / 2), sensor.card if sensor else None
    )
    labeller = TeacherLabeller(
        options.out, logs, method, settings, params, label_map, exclude, on_label, reader_options
    )
    record = {
        "method": method.name,
        "logs": [
            {
                "root": str(r.root),
                "format": r.format,
                "sequences": r.sequences(),
                "frames": sum(len(r.frames(s)) for s in r.sequences()),
                "fingerprint": log_fingerprint(r),
            }
            for r in logs
        ],
        "selection": asdict(params),
        "source_sensor": sensor.record() if sensor else None,
        "corrected": {
            "path": str(options.labels) if options.labels else None,
            "train": len(train),
            "held_back": len(heldout),
        },
    }
    try:
        trainer = AdaptTrainer(
            options.out,
            parent,
            cfg,
            labeller,
            source,
            train,
            heldout,
            probe,
            label_map,
            record,
            options.resume,
        )
        done = trainer.run(on_step=on_step)
    finally:
        source.close()
    last = done.training_data["adapt"]["rounds"][-1] if done.training_data["adapt"]["rounds"] else {}
    src = done.metrics[-1].get("val_source_miou", float("nan")) if done.metrics else float("nan")
    return (
        f"wrote adapted checkpoint {options.out.resolve()} (rounds {len(done.epochs)}, last round's "
        f"pseudo-label coverage {last.get('coverage', float('nan')):.3f}, source probe mIoU {src:.4f})"
    )


def _check_teacher_stages(method, settings: LabelSettings, parent: Path) -> None:
    """The teacher's stage configs validated before any stage runs (``--clusterer bogus`` was
    refused only after ingest, align and infer had run).

    Raises:
        ValueError: naming the option (``--clusterer 'bogus': not a kind it takes (expected: …)``).
    """
    from pydantic import ValidationError

    from tasks.methods import stage_config_line

    stages = method.stage_settings(settings.model_copy(update={"checkpoint": str(parent), "refine": True}))
    pipeline = method.pipeline(method.options(settings), stages)
    for name, config in stages.items():
        try:
            pipeline[name].Config.model_validate(config)
        except ValidationError as exc:
            raise ValueError(stage_config_line(name, exc)) from None


@dataclass(frozen=True)
class SourceSensor:
    """The LiDAR the synthetic source stream renders with (``--like LOG`` / ``--sensor-card CARD``).

    Attributes:
        option: ``"--like"`` or ``"--sensor-card"``; path: the log or card it came from (resolved).
        card: the :class:`~dsnet_core.sensor.card.SensorCard`.
    """

    option: str
    path: str
    card: object

    def record(self) -> dict:
        """What the adapted checkpoint's card records (and a resume compares)."""
        return {"option": self.option, "path": self.path, "card": self.card.model_dump(mode="json")}


def source_sensor(options: AdaptOptions) -> SourceSensor | None:
    """The source stream's sensor card from ``--like LOG`` (estimated) or ``--sensor-card CARD``.

    Raises:
        ConfigError: both given, or with ``--source-log`` (no stream to render).
        SensorCardError, SensorEstimateError, DataFormatError: a bad card or log (one line).
    """
    from dsnet_core.errors import ConfigError

    if options.like is None and options.sensor_card is None:
        return None
    if options.like is not None and options.sensor_card is not None:
        raise ConfigError("--like and --sensor-card both name the source stream's LiDAR: give one")
    if options.source_log is not None:
        flag = "--like" if options.like is not None else "--sensor-card"
        raise ConfigError(f"{flag} renders the synthetic source stream: it does not apply with --source-log")
    if options.sensor_card is not None:
        from dsnet_core.sensor import load_card

        path = Path(options.sensor_card).expanduser()
        return SourceSensor("--sensor-card", str(path.resolve()), load_card(path))
    from dsnet_core.io.formats import open_log
    from dsnet_core.sensor import estimate_sensor

    path = Path(options.like).expanduser()
    card = estimate_sensor(open_log(str(path)), path, name=path.resolve().name or "sensor").card
    return SourceSensor("--like", str(path.resolve()), card)


def _check_resumed_logs(
    options: AdaptOptions, logs: list, method: str, sensor: SourceSensor | None = None
) -> None:
    """A resume adapts to the logs (and with the method and selection) it was started with: a
    finished adaptation resumed with other logs would otherwise say "wrote adapted checkpoint",
    adapted to nothing new.

    Raises:
        ConfigError: naming the recorded and the given logs (or setting).
    """
    from dsnet_core.errors import ConfigError
    from dsnet_core.model.card import CARD, card_json

    if not options.resume or not (options.out / CARD).is_file():
        return
    adapt = (card_json(options.out).get("training_data") or {}).get("adapt")
    if adapt is None:
        return  # not an adaptation: the trainer refuses the folder
    recorded = [str(entry.get("root")) for entry in adapt.get("logs", [])]
    given = [str(r.root) for r in logs]
    changed = []
    if recorded != given:
        changed.append(f"LOG: {' '.join(recorded)} → {' '.join(given)}")
    else:
        prints = [entry.get("fingerprint") for entry in adapt.get("logs", [])]
        moved = [str(r.root) for r, p in zip(logs, prints, strict=True) if p and log_fingerprint(r) != p]
        if moved:
            changed.append(f"LOG {' '.join(moved)}: its scans changed since the adaptation started")
    was = adapt.get("source_sensor")
    now = sensor.record() if sensor else None
    if (was or {}).get("option") != (now or {}).get("option") or (was or {}).get("path") != (now or {}).get(
        "path"
    ):
        before = f"{was['option']} {was['path']}" if was else "the presets"
        after = f"{now['option']} {now['path']}" if now else "the presets"
        changed.append(f"the source stream's LiDAR: {before} → {after}")
    elif was and now and was.get("card") != now["card"]:
        changed.append(f"{now['option']} {now['path']}: its sensor changed since the adaptation started")
    if adapt.get("method") not in (None, method):
        changed.append(f"--method: {adapt['method']!r} → {method!r}")
    selection = adapt.get("selection") or {}
    for key in ("keep", "min_confidence", "max_confidence"):
        if key in selection and not math.isclose(selection[key], getattr(options, key)):
            changed.append(f"--{key.replace('_', '-')}: {selection[key]!r} → {getattr(options, key)!r}")
    if changed:
        raise ConfigError(
            f"{options.out} was adapted with other logs or settings: {'; '.join(changed)}. Resume with "
            "what it was started with, or adapt into another --out"
        )


def _parent(options: AdaptOptions, method) -> Path:
    """The checkpoint to adapt: ``--from``, else the method's bundled one; on a resume, the one the
    card records (a different ``--from`` is refused).

    Raises:
        CheckpointError, ValueError: none found, or a resume from another parent.
    """
    from dsnet_core.errors import CheckpointError
    from dsnet_core.model.card import CARD, read_card

    given = options.init_from.expanduser().resolve() if options.init_from else None
    if options.resume and (options.out / CARD).is_file():
        recorded = Path(
            read_card(options.out).training_data.get("adapt", {}).get("parent", {}).get("path", "")
        )
        if given is not None and given != recorded:
            raise ValueError(f"{options.out} adapts {recorded}: resume without --from, or with the same one")
        given = recorded
    if given is None:
        given = method.bundled_checkpoint(options.scans)
        if given is None:
            raise CheckpointError(options.out, "no bundled model for this method: pass --from CKPT")
    read_card(given)
    return given
