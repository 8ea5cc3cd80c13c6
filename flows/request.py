"""What one labelling run is asked to do: :class:`LabelRequest`, shared by the flows, ``dsnet label``,
``dsnet demo`` and the scheduled deployment of ``dsnet serve``.

The command-line settings that shape the stages (:class:`~tasks.methods.LabelSettings`) become
per-stage configs through the method (:meth:`LabelRequest.from_settings`); nothing here names one.
"""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ConfigDict, Field, field_validator

from tasks.base import RunOptions
from tasks.ingest import IngestStage
from tasks.methods import DEFAULT_METHOD, LabelSettings, Method, get_method
from tasks.pipeline import Pipeline
from tasks.run_config import RunConfig, build_run_config


class LabelRequest(BaseModel):
    """One labelling run.

    Attributes:
        data: the log's root (any registered format).
        root: the run store (a folder or ``s3://bucket/prefix``).
        sequences: sequences to label (None: every sequence of the log).
        format: the log's format name, or ``auto`` to detect it.
        reader_options: keyword options of the format's reader (``{"topic": "/points"}``,
            ``{"sweeps": True}``); recorded in the run config so every stage opens the log alike.
        method: the method (:data:`tasks.methods.METHODS`) and ``method_options`` its factory's options.
        stages: per-stage config overrides (``{"align": {"scans": 2}}``).
        options: run-level policy (error handling, block size, locks).
        from_stage: recompute this stage and everything downstream.
        until: stop after this stage (default: run every stage).
        force: recompute every stage.
        storage_options: fsspec options of the run store.
    """

    model_config = ConfigDict(extra="forbid")

    data: str
    root: str
    sequences: list[str] | None = None
    format: str = "auto"
    reader_options: dict[str, Any] = Field(default_factory=dict)
    method: str = DEFAULT_METHOD
    method_options: dict[str, Any] = Field(default_factory=dict)
    stages: dict[str, dict[str, Any]] = Field(default_factory=dict)
    options: RunOptions = Field(default_factory=RunOptions)
    from_stage: str | None = None
    until: str | None = None
    force: bool = False
    storage_options: dict[str, Any] = Field(default_factory=dict)

    @field_validator("sequences")
    @classmethod
    def _plain_sequence_names(cls, value: list[str] | None) -> list[str] | None:
        from storage.errors import StoreError
        from storage.names import check_plain_name

        for name in value or []:
            try:
                check_plain_name(name)
            except StoreError as exc:
                raise ValueError(str(exc)) from exc
        return value

    @classmethod
    def from_settings(cls, settings: LabelSettings, **fields: Any) -> LabelRequest:
        """A request whose method options and stage configs come from the command line's settings
        (the method's :meth:`~tasks.methods.base.Method.stage_settings`); ``fields`` are the rest.

        Raises:
            ValueError: an unknown method, or a setting the method does not take.
        """
        method = get_method(fields.get("method"))
        return cls(**fields, method_options=method.options(settings), stages=method.stage_settings(settings))

    def the_method(self) -> Method:
        """The request's method. Raises ValueError for an unknown name."""
        return get_method(self.method)

    def pipeline(self) -> Pipeline:
        """The method's stages. Raises ValueError for an unknown method or stage name."""
        pipeline = self.the_method().pipeline(self.method_options, self.stages)
        for name in (self.from_stage, self.until, *self.stages):
            pipeline.check_stage(name)
        return pipeline

    def check(self) -> None:
        """Check what can be checked before any server or stage starts: the method and the stage
        names, the log (its format and reader options), the model the stages name (its card) and
        the run store (a folder, or an S3 endpoint that answers to these credentials); each stage's
        config against the stage's ``Config`` (``--clusterer bogus`` is refused here, naming the
        option, not after three stages ran).

        Raises:
            ValueError, DataFormatError, CheckpointError, StoreError: naming what is wrong.
        """
        from pydantic import ValidationError

        from storage.fs import RootFS
        from tasks.methods import stage_config_line

        pipeline = self.pipeline()
        RootFS(self.root, self.storage_options).check()  # cheap: before the model card loads torch
        self.open_log()
        for name, config in self.stage_configs(pipeline, self.order(pipeline)).items():
            try:
                pipeline[name].Config.model_validate(config)
            except ValidationError as exc:
                raise ValueError(stage_config_line(name, exc)) from None

    def order(self, pipeline: Pipeline) -> list[str]:
        """The stages this run executes, in order."""
        return pipeline.until(self.until)

    def forced(self, pipeline: Pipeline) -> set[str]:
        """The stages this run recomputes whatever their manifests say."""
        if self.force:
            return set(pipeline.names())
        if self.from_stage:
            return {self.from_stage, *pipeline.downstream_of(self.from_stage)}
        return set()

    def open_log(self):
        """The log's reader, opened with the request's format and reader options.

        Raises:
            DataFormatError: unknown format, nothing detected, or an option the reader lacks.
        """
        from dsnet_core.io.formats import open_log

        return open_log(self.data, self.format, self.reader_options)

    def stage_configs(self, pipeline: Pipeline, names: list[str] | None = None) -> dict[str, dict[str, Any]]:
        """The configs the run records for ``names`` (default: every stage of the pipeline): the
        request's overrides, and ingest's ``grid`` from the method's model (the checkpoint the
        configs name, else its bundled one: :meth:`~tasks.methods.base.Method.model_grid`) unless
        the request sets it.

        Raises:
            CheckpointError: the named checkpoint has no model card.
        """
        names = pipeline.names() if names is None else names
        out = {name: dict(self.stages.get(name, {})) for name in names}
        if IngestStage.name in out and out[IngestStage.name].get("grid") is None:
            grid = self.the_method().model_grid(self.stages)
            if grid is not None:
                out[IngestStage.name]["grid"] = grid
        return out

    def run_config(
        self, pipeline: Pipeline, log_format: str, sequences: list[str] | None = None, **record: Any
    ) -> RunConfig:
        """The run config a run of this request records and its fingerprints read (the one builder:
        the run record, the pending check of ``dsnet label`` and ``serve``'s survey): the log where
        it is from any directory, its detected ``log_format``, the reader options, the method and
        its recorded options, each executed stage's config (:meth:`stage_configs`) and the run
        options; ``record`` adds the run's own fields (``run_id``, ``code_version``, ...).

        Raises:
            CheckpointError: the named checkpoint has no model card.
        """
        return build_run_config(
            pipeline,
            resolved_location(str(self.data)),
            log_format,
            reader_options=self.reader_options,
            sequences=sequences,
            stages=self.stage_configs(pipeline, self.order(pipeline)),
            options=self.options,
            **record,
        )

    def dataset_name(self) -> str:
        """A short name of the log (its folder's name), for artifact keys."""
        return str(self.data).rstrip("/").rsplit("/", 1)[-1]


def resolved_location(data: str) -> str:
    """Where a log is, independent of the working directory: a local path made absolute, a URL as
    given (what the run config records, so a run folder accepts its log from any directory)."""
    from pathlib import Path

    return data if "://" in data else str(Path(data).expanduser().resolve())


def parse_reader_options(pairs: list[str] | None, **named: Any) -> dict[str, Any]:
    """``["topic=/points", "sweeps=true"]`` -> ``{"topic": "/points", "sweeps": True}``: values are
    YAML scalars (``true``, ``5``, ``0.1``; anything else stays a string). ``named`` options (the
    command line's ``--topic``, ``--fixed-frame``) are added where not None; naming one both ways
    with different values is an error.

    Raises:
        ValueError: an entry without ``=`` or with an empty key.
    """
    import yaml

    out: dict[str, Any] = {}
    for pair in pairs or []:
        key, sep, value = pair.partition("=")
        key = key.strip().replace("-", "_")
        if not sep or not key:
            raise ValueError(f"--reader-option {pair!r}: expected KEY=VALUE (e.g. topic=/points)")
        try:
            parsed = yaml.safe_load(value) if value.strip() else ""
        except yaml.YAMLError:
            parsed = value
        out[key] = parsed if isinstance(parsed, str | int | float | bool) else value
    for key, value in named.items():
        if value is None:
            continue
        if key in out and out[key] != value:
            raise ValueError(f"reader option {key!r} given twice: {out[key]!r} and {value!r}")
        out[key] = value
    return out
