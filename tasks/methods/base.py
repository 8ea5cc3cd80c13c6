"""What a labelling method is: :class:`Method`, and the settings it is given (:class:`LabelSettings`).

A method is one object in one module of this package: its stages (:meth:`Method.pipeline`), the
command-line settings it accepts and how they become stage configs (:meth:`Method.stage_settings`),
its model grid, its bundled checkpoints, and its trainer (:attr:`Method.TrainOptions`,
:meth:`Method.train`). The flows and the command line ask the registry (:mod:`tasks.methods`) for a
method by name and never name one themselves; stages check what their source stage declares.
"""

from __future__ import annotations

import json
import re
from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator

if TYPE_CHECKING:
    from dsnet_core.checkpoints import Checkpoints
    from tasks.pipeline import Pipeline

Temporal = Literal["auto", "stitch", "track"]
TEMPORAL_KINDS = ("stitch", "track")
"""How instance ids become sequence-wide: stitching overlapping volumes, or tracking instances."""
REFINE_DEFAULT = True
"""Whether a method's pipeline ends with the ``refine`` stage when the run does not say
(``dsnet label --refine/--no-refine``); chosen by ``bench/bench_refine.py`` (docs/refine.md)."""
DEVICE = re.compile(r"^(cpu|cuda(:\d+)?)$")


def check_device(value: str | None) -> str | None:
    """``cpu``, ``cuda`` or ``cuda:N`` (None: the default); anything else is a ValueError."""
    if value is not None and not DEVICE.match(value):
        raise ValueError(f"--device {value!r}: expected cpu, cuda or cuda:N")
    return value


INPUT, METHOD, MODEL = "Input", "Method", "Model"
"""Help panels of the label options (``json_schema_extra={"panel": ...}`` of a field)."""


def option(default: Any, description: str, panel: str, **constraints: Any) -> Any:
    """A label setting's field: its default, its help text and its help panel (``Input``,
    ``Method``, ``Model``), with pydantic ``constraints`` (``ge=1``)."""
    return Field(default, description=description, json_schema_extra={"panel": panel}, **constraints)


class LabelSettings(BaseModel):
    """The labelling settings of the command line (``dsnet label``, ``serve``, ``demo``): the ones
    every method takes are fields here; a method declares the rest once, as fields of its own
    subclass (:attr:`Method.Settings`), which the command line turns into its flags (each field's
    description its help). A ``LabelSettings`` may carry any method's settings (extra fields);
    :meth:`Method.settings_of` validates them against the method's model and refuses the others by
    their flag."""

    model_config = ConfigDict(extra="allow", frozen=True)

    scans: int | None = option(
        None,
        "k: scans per 4D volume (1 = 3D panoptic); default: the method's (`dsnet config dump`).",
        METHOD,
        ge=1,
        le=16,
    )
    checkpoint: str | None = option(None, "Model checkpoint folder (default: the bundled model).", MODEL)
    estimate_poses: bool = option(
        False,
        "KISS-ICP poses for sequences without poses.txt (the \\[odometry] extra; log poses win).",
        INPUT,
    )
    max_points: int | None = option(None, "Refuse frames with more points (default 2,000,000).", INPUT, ge=1)
    device: str | None = option(None, "cpu (default), cuda or cuda:N.", MODEL)
    refine: bool | None = option(
        None,
        "Refine the whole sequence offline (static-world vote, one class per track, tracks joined "
        "across gaps); default: the method's (docs/refine.md). Switching recomputes refine and score.",
        METHOD,
    )

    @field_validator("device")
    @classmethod
    def valid_device(cls, value: str | None) -> str | None:
        return check_device(value)

    def given(self) -> list[str]:
        """The settings that differ from their defaults (extra ones: every one given)."""
        fields = type(self).model_fields
        out = [name for name, f in fields.items() if getattr(self, name) != f.default]
        return out + list(self.model_extra or {})

    def given_values(self) -> dict[str, Any]:
        """The settings given when it was made (its fields set explicitly and its extra ones)."""
        return {name: getattr(self, name) for name in self.model_fields_set} | dict(self.model_extra or {})


class TemporalSettings(LabelSettings):
    """Settings of a method whose volumes follow each other (``--stride``) and whose ids become
    sequence-wide by stitching or tracking (``--temporal``)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    stride: int | None = option(None, "Step between volumes (default k-1).", METHOD, ge=1)
    temporal: Temporal = option(
        "auto", "Sequence-wide ids: stitch (k > 1), track, or auto (track at k = 1, else stitch).", METHOD
    )


CLUSTERER_HELP = "dynamic_shift, meanshift, dbscan, hdbscan, bfs, or a JSON config"


SHARED_SETTINGS = frozenset(LabelSettings.model_fields)
"""Settings every method takes."""


def flag(name: str) -> str:
    """The command-line flag of a setting: ``tta_flip`` → ``--tta-flip``."""
    return "--" + name.replace("_", "-")


INGEST_KEYS: dict[str, tuple[str, ...]] = {
    "estimate_poses": ("ingest.estimate_poses",),
    "max_points": ("ingest.max_points",),
}
"""The stage config keys the shared input settings write (every method shares ingest)."""


class TrainOptions(BaseModel):
    """Training settings every method's trainer takes (``dsnet train METHOD``); a method extends it.

    Fields become the command's options (their descriptions its help); ``data`` is its argument.
    """

    model_config = ConfigDict(extra="forbid")

    data: Path | None = Field(None, description="Training log root (any format with labels).")
    out: Path = Field(..., description="Checkpoint folder (written every epoch).")
    epochs: str = Field("10", description="Epochs: N for every stage, or per stage 'a=N,b=M'.")
    device: str = Field("cpu", description="cpu, cuda or cuda:N.")
    resume: bool = Field(False, description="Continue the checkpoint in --out.")
    init_from: Path | None = Field(
        None, description="Start from this checkpoint's weights ('bundled': the method's bundled model)."
    )
    sequences: str | None = Field(None, description="Comma-separated training sequences (default: all).")
    val_data: Path | None = Field(None, description="Validation log root (default: DATA).")
    val_sequences: str | None = Field(None, description="Validation sequences (default: the training ones).")
    lr: float = Field(1e-3, gt=0, description="Adam learning rate (the start of each stage's schedule).")
    seed: int = Field(0, ge=0, description="Seed of initialisation, shuffling and augmentation.")
    augment: bool = Field(True, description="Yaw, flip, scale and translation augmentation.")
    threads: int = Field(1, ge=1, description="Torch CPU threads.")

    @field_validator("device")
    @classmethod
    def valid_device(cls, value: str) -> str:
        return check_device(value) or "cpu"

    def check_paths(self) -> None:
        """The input paths exist, checked before torch and the trainer are imported (seconds): DATA,
        ``--val-data`` and an ``--init-from`` checkpoint folder (its card).

        Raises:
            UnknownLogFormatError: no such log; CheckpointError: no readable card.
        """
        from dsnet_core.io.formats import UnknownLogFormatError
        from dsnet_core.model.card import card_json

        for path in (self.data, self.val_data):
            if path is not None and not Path(path).expanduser().exists():
                raise UnknownLogFormatError(Path(path).expanduser(), "no such file or folder")
        if self.init_from is not None and str(self.init_from) != "bundled":
            card_json(self.init_from)

    def epoch_counts(
        self, stages: tuple[str, ...], default_all: tuple[str, ...] | None = None
    ) -> dict[str, int]:
        """``--epochs``: ``"10"`` → 10 for each of ``default_all`` (default: every stage), 0 for the
        rest; ``"a=3,b=1"`` → per stage, unnamed stages 0.

        Raises:
            ValueError: an unknown stage, a count that is not a whole number ≥ 0, or 0 epochs for
                every stage (nothing would be trained, yet a checkpoint written).
        """
        out = self._epoch_counts(stages, default_all)
        if not any(out.values()):
            raise ValueError(
                f"--epochs {self.epochs!r}: 0 epochs for every stage ({', '.join(stages)}) would write an "
                "untrained checkpoint; give N ≥ 1"
            )
        return out

    def _epoch_counts(
        self, stages: tuple[str, ...], default_all: tuple[str, ...] | None = None
    ) -> dict[str, int]:
        out = dict.fromkeys(stages, 0)
        try:
            if "=" not in self.epochs:
                n = int(self.epochs)
                if n < 0:
                    raise ValueError
                return {s: (n if s in (default_all or stages) else 0) for s in stages}
            for part in self.epochs.split(","):
                name, _, value = part.partition("=")
                if name.strip() not in out:
                    raise ValueError(
                        f"--epochs: unknown stage {name.strip()!r} (stages: {', '.join(stages)})"
                    )
                out[name.strip()] = int(value)
                if out[name.strip()] < 0:
                    raise ValueError
        except ValueError as exc:
            if str(exc).startswith("--epochs"):
                raise
            raise ValueError(f"--epochs {self.epochs!r}: expected N or stage=N,... with N ≥ 0") from None
        return out

    def start_from(self, method: Method, scans: int = 1) -> Path | None:
        """``init_from``, with ``bundled`` resolved to ``method``'s bundled checkpoint for k = ``scans``.

        Raises:
            ValueError: ``bundled`` asked for and the package holds no such model.
        """
        if self.init_from is None or str(self.init_from) != "bundled":
            return self.init_from
        found = method.bundled_checkpoint(scans)
        if found is None:
            raise ValueError(f"--init-from bundled: no bundled {method.name} model for k = {scans}")
        return found

    def names(self, text: str | None) -> list[str] | None:
        """A comma-separated option as a list (None when not given)."""
        return [v.strip() for v in text.split(",") if v.strip()] if text else None


StepCallback = Callable[[str, int, int, int, float], None]
"""``(stage, epoch, step, steps, loss)`` after every training step (progress bars)."""


class Method(ABC):
    """A labelling method. Subclasses set the class attributes and implement the abstract methods.

    Attributes:
        name: the name runs record and ``--method`` takes.
        title: one line for help texts.
        default_scans: k when ``--scans`` is not given.
        Settings: its label settings, declared once (a :class:`LabelSettings` subclass: the shared
            fields and its own); ``dsnet label``, ``serve`` and ``demo`` make their flags of it.
        stage_keys: the stage config keys each setting writes (``"tta": ("infer.tta",)``): what a
            flag given on the command line overrides in a ``--config`` file.
        TrainOptions: its trainer's options (a :class:`TrainOptions` subclass).
        data_parallel: whether its trainer runs under torchrun with several processes.
        adaptable: whether ``dsnet adapt`` can self-train its network on unlabelled logs (a network
            with a semantic head and probabilities its infer stage stores; ``docs/adapt.md``).
        checkpoints: its checkpoints (:class:`dsnet_core.checkpoints.Checkpoints`: the bundled
            models, resolving one, its card kind); None for a method without a network.
        homes: the modules besides its own where its name may be written (its trainer, its stages:
            ``tests/test_layers.py`` reads them from the registry).
    """

    name: ClassVar[str]
    title: ClassVar[str]
    default_scans: ClassVar[int]
    Settings: ClassVar[type[LabelSettings]] = LabelSettings
    stage_keys: ClassVar[Mapping[str, tuple[str, ...]]] = INGEST_KEYS
    TrainOptions: ClassVar[type[TrainOptions]] = TrainOptions
    data_parallel: ClassVar[bool] = False
    adaptable: ClassVar[bool] = False
    checkpoints: ClassVar[Checkpoints | None] = None
    homes: ClassVar[tuple[str, ...]] = ()

    # -- labelling -----------------------------------------------------------------------------
    @abstractmethod
    def pipeline(
        self, options: Mapping[str, Any] | None = None, stages: Mapping[str, Mapping[str, Any]] | None = None
    ) -> Pipeline:
        """The method's stages, built with its recorded ``options`` (``method_options``); ``stages``
        (the run's stage configs) settle what depends on them (e.g. the temporal association at
        k = 1).

        Raises:
            ValueError: an option the method does not take, or a bad value.
        """

    @property
    def settings(self) -> frozenset[str]:
        """The settings it takes besides :data:`SHARED_SETTINGS` (its :attr:`Settings`' own fields)."""
        return frozenset(self.Settings.model_fields) - SHARED_SETTINGS

    def settings_of(self, settings: LabelSettings) -> LabelSettings:
        """``settings`` as this method's :attr:`Settings` (validated).

        Raises:
            ValueError: naming every given setting the method does not take.
            pydantic.ValidationError: a bad value of one it takes.
        """
        if type(settings) is self.Settings and not settings.model_extra:
            return settings
        self.refuse(settings)
        given = settings.given_values()
        return self.Settings(**{k: v for k, v in given.items() if k in self.Settings.model_fields})

    def options(self, settings: LabelSettings) -> dict[str, Any]:
        """The ``method_options`` a run records for ``settings`` (keys are setting names)."""
        settings = self.settings_of(settings)
        temporal = getattr(settings, "temporal", "auto")
        out: dict[str, Any] = {} if temporal == "auto" else {"temporal": temporal}
        if settings.refine is not None:
            out["refine"] = settings.refine
        return out

    @abstractmethod
    def stage_configs(self, settings: LabelSettings) -> dict[str, dict[str, Any]]:
        """Per-stage config overrides for ``settings`` (an instance of :attr:`Settings`); a setting
        writes only the keys :attr:`stage_keys` lists for it."""

    def stage_settings(self, settings: LabelSettings) -> dict[str, dict[str, Any]]:
        """Refuse the settings this method lacks, then :meth:`stage_configs`.

        Raises:
            ValueError: naming every refused flag.
        """
        return self.stage_configs(self.settings_of(settings))

    def refuse(self, settings: LabelSettings) -> None:
        """Raise ValueError naming every given setting the method does not take."""
        bad = [n for n in settings.given() if n not in self.Settings.model_fields]
        if bad:
            raise ValueError(
                f"{', '.join(flag(n) for n in bad)}: not a setting of method {self.name} "
                f"({self.title}); see dsnet label --help"
            )

    def scans(self, settings: LabelSettings) -> int:
        return settings.scans if settings.scans is not None else self.default_scans

    @abstractmethod
    def model_grid(self, stages: Mapping[str, Mapping[str, Any]]) -> dict[str, list[float]] | None:
        """The grid bounds of the model the stage configs name (the bundled one when they name
        none), which ingest records; None when there is no model to ask."""

    def bundled_checkpoint(self, scans: int) -> Path | None:
        """The bundled checkpoint for k = ``scans`` (its :attr:`checkpoints`'), or None when the
        package has none."""
        return None if self.checkpoints is None else self.checkpoints.bundled(scans)

    # -- training ------------------------------------------------------------------------------
    @abstractmethod
    def train(self, options: TrainOptions, on_step: StepCallback | None = None) -> str:
        """Train (or resume) a checkpoint with ``options``; returns a one-line summary of the result.

        Raises:
            DsnetError: bad data or settings.
        """


def resolve_temporal(
    options: Mapping[str, Any] | None, stages: Mapping[str, Mapping[str, Any]] | None
) -> str:
    """``options["temporal"]``; ``auto`` (or none): tracking at k = 1 (volumes share no frame, so
    stitching could only hand out fresh ids), stitching for k > 1 — k from the stage configs'
    ``align.scans``; stitching when no stage configs are given.

    Raises:
        ValueError: an unknown association.
    """
    temporal = (options or {}).get("temporal", "auto")
    if temporal == "auto":
        if stages is None:
            return "stitch"
        return "track" if int(stages.get("align", {}).get("scans", 1)) == 1 else "stitch"
    if temporal not in TEMPORAL_KINDS:
        raise ValueError(f"unknown temporal association {temporal!r}; choose one of {list(TEMPORAL_KINDS)}")
    return temporal


def refined(pipeline: Pipeline, options: Mapping[str, Any] | None) -> Pipeline:
    """``pipeline`` with the offline ``refine`` stage (:mod:`tasks.refine`) between its labels stage
    and ``score``, which then scores the refined labels; unchanged with ``refine`` off (the option,
    else :data:`REFINE_DEFAULT`). The choice is recorded in the pipeline's options."""
    from tasks.pipeline import Pipeline
    from tasks.refine import RefineStage
    from tasks.score import ScoreStage

    refine = bool((options or {}).get("refine", REFINE_DEFAULT))
    recorded = (*pipeline.options, ("refine", refine))
    if not refine:
        return Pipeline(pipeline.name, pipeline.stages, pipeline.labels, recorded)
    stages = tuple(s for s in pipeline.stages if not isinstance(s, ScoreStage))
    stages += (RefineStage(labels=pipeline.labels), ScoreStage(labels="refine"))
    return Pipeline(pipeline.name, stages, labels="refine", options=recorded)


def check_options(name: str, options: Mapping[str, Any] | None, known: tuple[str, ...]) -> None:
    """Raise ValueError for a method option the method does not take."""
    unknown = sorted(set(options or {}) - set(known))
    if unknown:
        raise ValueError(
            f"method {name} takes no option {', '.join(unknown)} (its options: {', '.join(known)})"
        )


def clusterer_config(clusterer: str) -> dict[str, Any]:
    """``--clusterer``: a kind (``dbscan``) or a JSON config. Raises ValueError for bad JSON."""
    try:
        return json.loads(clusterer) if clusterer.lstrip().startswith("{") else {"kind": clusterer}
    except json.JSONDecodeError as exc:
        raise ValueError(f"--clusterer is not valid JSON: {exc}") from None


def ingest_settings(settings: LabelSettings) -> dict[str, dict[str, Any]]:
    """Ingest's settings of the command line (every method shares ingest)."""
    ingest: dict[str, Any] = {"estimate_poses": True} if settings.estimate_poses else {}
    if settings.max_points is not None:
        ingest["max_points"] = settings.max_points
    return {"ingest": ingest} if ingest else {}


def align_settings(scans: int, stride: int | None) -> dict[str, dict[str, Any]]:
    return {"align": {"scans": scans, **({"stride": stride} if stride else {})}}


def absolute(path: str | Path | None) -> str | None:
    """A user path made absolute (``~`` expanded), as the run records it; None stays None."""
    return None if path is None else str(Path(path).expanduser().resolve())


def grid_of(bounds) -> dict[str, list[float]]:
    """A :class:`~dsnet_core.model.presets.GridConfig`'s bounds as ingest records them."""
    return {"min_bound": list(bounds.min_bound), "max_bound": list(bounds.max_bound)}
