"""The run config: what a labelling run recorded in its store (``run.json``) and every stage reads.

One typed object instead of a dict: the flows build it once (:func:`flows.run_record.record_run`),
the store keeps its JSON, and stages, export, review and the report read it back through
:meth:`RunConfig.of`. :meth:`RunConfig.open_log` is the one way to open the run's log.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

from pydantic import BaseModel, ConfigDict, Field

from storage.run import STORE_FORMAT
from tasks.base import RunOptions

if TYPE_CHECKING:
    from dsnet_core.io.reader import LogReader
    from tasks.base import Stage, StageConfig
    from tasks.pipeline import Pipeline


class RunConfig(BaseModel):
    """A run's recorded settings.

    Attributes:
        data: the log's root (a path as resolved when the run started, or a URL).
        format: the log's format name (detected and recorded; ``auto`` only in hand-made configs).
        reader_options: keyword options of the format's reader.
        method: the labelling method (a name in :data:`tasks.methods.METHODS`).
        method_options: the options its pipeline was built with (``{"temporal": "track"}``).
        stage_versions: each stage's code version when the run started.
        labels_stage: the stage whose per-frame ``label`` array holds the final labels.
        sequences: the sequences the run labelled.
        stages: per stage, its config as recorded (validated by the stage's ``Config``).
        options: run-level policy.
        run_id, code_version, host, started, finished, summary: the run's record.
        store_format: the run store's format version (:data:`storage.run.STORE_FORMAT`).
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    data: str
    format: str = "auto"
    reader_options: dict[str, Any] = Field(default_factory=dict)
    method: str = ""
    method_options: dict[str, Any] = Field(default_factory=dict)
    stage_versions: dict[str, str] = Field(default_factory=dict)
    labels_stage: str | None = None
    sequences: list[str] = Field(default_factory=list)
    stages: dict[str, dict[str, Any]] = Field(default_factory=dict)
    options: RunOptions = Field(default_factory=RunOptions)
    run_id: str | None = None
    code_version: str = ""
    host: str = ""
    started: float = 0.0
    finished: float | None = None
    summary: list[dict[str, Any]] | None = None
    store_format: int = STORE_FORMAT

    @classmethod
    def of(cls, run: RunConfig | Mapping[str, Any]) -> RunConfig:
        """``run`` itself, or the config a recorded (or hand-made) dict describes."""
        return run if isinstance(run, RunConfig) else cls.model_validate(dict(run))

    def open_log(self) -> LogReader:
        """The log's reader, opened as the run recorded it.

        Raises:
            DataFormatError: the log is gone, or no longer reads as the recorded format.
        """
        from dsnet_core.io.formats import open_log

        return open_log(self.data, self.format, self.reader_options)

    def pipeline(self) -> Pipeline:
        """The recorded method's stages, built with its recorded options."""
        from tasks.methods import get_method

        return get_method(self.method or None).pipeline(self.method_options, self.stages)

    def labels(self) -> str:
        """The stage holding the final per-frame labels: as recorded, else the recorded method's."""
        return self.labels_stage or self.pipeline().labels

    def stage_config(self, stage: Stage) -> StageConfig:
        """``stage``'s config as recorded, validated, with its defaults filled in.

        Raises:
            pydantic.ValidationError: a recorded key the stage does not know, or a bad value.
        """
        return stage.Config.model_validate(self.stages.get(stage.name, {}))


def build_run_config(
    pipeline: Pipeline,
    data: str,
    log_format: str,
    *,
    reader_options: Mapping[str, Any] | None = None,
    sequences: list[str] | None = None,
    stages: Mapping[str, Mapping[str, Any]] | None = None,
    options: RunOptions | None = None,
    **record: Any,
) -> RunConfig:
    """The one builder of a run's config (``dsnet label``'s request, its pending check, ``serve``'s
    survey and ``dsnet adapt``'s teacher): the pipeline's record (method, its options, stage
    versions, labels stage), the log (``data`` as the caller resolved it, its ``log_format`` and
    ``reader_options``), the sequences, each stage's config and the run options; ``record`` adds
    the run's own fields (``run_id``, ``code_version``, ...).
    """
    return RunConfig(
        **pipeline.record(),
        data=data,
        format=log_format,
        reader_options=dict(reader_options or {}),
        sequences=list(sequences or []),
        stages={name: dict(config) for name, config in (stages or {}).items()},
        options=options or RunOptions(),
        **record,
    )


def read_run(store, run_id: str | None = None) -> RunConfig:
    """The run config ``store`` records (the latest run's, or ``run_id``'s).

    Raises:
        StoreError: no run config there, or one of another store format.
    """
    return RunConfig.of(store.read_run_config(run_id))
