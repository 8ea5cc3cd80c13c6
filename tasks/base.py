"""What a stage declares to plug into the pipeline, and the context its block function gets.

A stage is one class: its ``name``, ``upstream`` stages, a ``version`` (bump it when the output
changes), a pydantic ``Config``, the unit of its arrays (``item``: ``frame`` or ``volume``), the
arrays and tables it writes (:class:`~storage.contract.ArraySpec`, :class:`~storage.contract.TableSpec`),
and two functions: ``plan`` (how many items, how big) and ``run_block`` (store -> dsnet_core ->
yielded item results). A method is a list of stages (:mod:`tasks.pipeline`); the shared runner
(:mod:`tasks.runner`) does everything else: fingerprints, skip/resume/clear, writing arrays with
``done`` last, block fragments, tables and the manifest.

Stages never name a dataset: the model's label map comes from the run's model stage (its
manifest records the checkpoint card's class map), the ground truth's from the log's reader.
"""

from __future__ import annotations

import time
from abc import ABC, abstractmethod
from collections.abc import Iterator
from dataclasses import dataclass, field
from functools import cached_property
from typing import TYPE_CHECKING, Any, ClassVar, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from storage.contract import ArraySpec, StageContract, TableSpec
from storage.errors import StoreError
from storage.run import RunStore

if TYPE_CHECKING:
    from dsnet_core.io.reader import LogReader
    from dsnet_core.labels import LabelMap
    from storage.arrays import StageArrays
    from storage.manifest import Manifest
    from tasks.frames import FrameValues
    from tasks.pipeline import Pipeline
    from tasks.run_config import RunConfig

CLASS_MAP = "class_map"
"""The plan key under which a model stage records its checkpoint's class map for downstream stages."""

FRAME_LABEL = ArraySpec(
    "label",
    "uint32",
    doc="raw semantic | sequence-wide instance id << 16, in the frame's original point order",
)
"""The final per-frame labels: the array every method's labels stage declares (item = frame,
indexed like the ingest frame table); export, score and the report read it."""


def labels_contract(stage: str) -> StageContract:
    """The part of a labels stage's contract that readers of final labels rely on."""
    return StageContract(stage, "frame", (FRAME_LABEL,))


class StageConfig(BaseModel):
    """Base of every stage config: frozen, unknown keys rejected."""

    model_config = ConfigDict(frozen=True, extra="forbid")


class RunOptions(BaseModel):
    """Run-level policy. Not part of any fingerprint: it does not change what a finished stage holds."""

    model_config = ConfigDict(extra="forbid")

    on_error: Literal["fail", "skip"] = "fail"  # skip: quarantine bad frames and go on
    block_size: int = Field(25, ge=1)  # items per task
    lock_wait_s: float = Field(0.0, ge=0)  # how long a second run waits for a held lock
    stale_after_s: float = Field(60.0, gt=0)  # heartbeat age after which a lock is abandoned
    heartbeat_s: float = Field(5.0, gt=0)


@dataclass
class Plan:
    """What a stage will produce for one sequence.

    Attributes:
        n_items: number of items (frames or volumes).
        max_points: padded row length of the per-point arrays.
        omit: optional arrays of the contract not written (e.g. labels of an unlabelled log).
        meta: small JSON-able facts the block function needs (stored in the manifest).
        blocks: the item indices of each block, overriding ``RunOptions.block_size`` (e.g. one
            block per sequence for a stage that is sequential over its items).
        dims: sizes of the named trailing dimensions of the stage's arrays (``{"classes": 20}``).
    """

    n_items: int
    max_points: int = 0
    omit: tuple[str, ...] = ()
    meta: dict[str, Any] = field(default_factory=dict)
    blocks: list[list[int]] | None = None
    dims: dict[str, int] = field(default_factory=dict)


@dataclass
class ItemResult:
    """One item's output. ``arrays`` must match the contract; ``rows`` are table rows by table name."""

    index: int
    arrays: dict[str, np.ndarray] = field(default_factory=dict)
    n_points: int = 0
    rows: dict[str, list[dict[str, Any]]] = field(default_factory=dict)
    counts: dict[str, int] = field(default_factory=dict)


class Stage(ABC):
    """A pipeline stage. Subclasses set the class attributes and implement plan/run_block.

    ``upstream`` may be set per instance (a stage parametrised by what it reads, e.g. ``score``
    reads whichever stage holds a method's final labels).
    """

    name: ClassVar[str]
    upstream: tuple[str, ...] = ()
    version: ClassVar[str]
    Config: ClassVar[type[StageConfig]] = StageConfig
    item: ClassVar[str] = "frame"
    arrays: ClassVar[tuple[ArraySpec, ...]] = ()
    tables: ClassVar[tuple[TableSpec, ...]] = ()

    @property
    def contract(self) -> StageContract:
        return StageContract(self.name, self.item, self.arrays, self.tables)

    def table(self, name: str) -> TableSpec:
        return self.contract.table(name)

    def inputs(self, ctx: StageContext) -> str:
        """Digest of inputs from outside the store (cheap: sizes and times, not content)."""
        return ""

    def check_sources(self, pipeline: Pipeline) -> None:
        """Raise ValueError when a stage this one reads does not declare what it reads (called by
        :class:`~tasks.pipeline.Pipeline` as it is built; the default checks nothing)."""
        return None

    def reads(self, pipeline: Pipeline) -> dict[str, tuple[str, ...]]:
        """The arrays this stage reads of stages further up than its ``upstream`` (``{"align":
        ("points",)}``): a stage reads arrays and tables only of itself, its ``upstream`` and these
        (:meth:`StageContext.arrays` refuses the others). They must be upstream of one of its
        ``upstream`` stages, so its fingerprint covers them through theirs (declaring them changes
        no fingerprint); :class:`~tasks.pipeline.Pipeline` checks that they declare the arrays."""
        return {}

    def sources(self, pipeline: Pipeline) -> frozenset[str]:
        """The stages whose arrays and tables this one reads: ``upstream`` and :meth:`reads`."""
        return frozenset((*self.upstream, *self.reads(pipeline)))

    def require(self, pipeline: Pipeline, source: str, arrays: tuple[str, ...]) -> None:
        """Raise ValueError unless stage ``source`` of ``pipeline`` declares ``arrays``."""
        declared = {a.name for a in pipeline[source].arrays}
        missing = [a for a in arrays if a not in declared]
        if missing:
            raise ValueError(
                f"stage {self.name!r} reads arrays {missing} of stage {source!r}, which declares "
                f"{sorted(declared) or 'none'}"
            )

    @abstractmethod
    def plan(self, ctx: StageContext) -> Plan:
        """Items and sizes for one sequence (runs once per fresh stage run)."""

    @abstractmethod
    def run_block(self, ctx: StageContext, items: list[int]) -> Iterator[ItemResult]:
        """Compute the given items, yielding one result per item (the runner writes them)."""

    def __repr__(self) -> str:
        return f"{type(self).__name__}(name={self.name!r}, upstream={self.upstream})"


@dataclass
class StageContext:
    """Everything a stage function may read. Built by the runner, in any process (threads, Dask).

    Attributes:
        store: the run store.
        sequence: the sequence being processed.
        stage: the stage's name.
        config: its validated config (an instance of the stage's ``Config``).
        run: the run config (data, format, stages, options).
        pipeline: the run's stages (to find other stages' declarations).
        plan: the stage's plan meta (empty while planning).
    """

    store: RunStore
    sequence: str
    stage: str
    config: StageConfig
    run: RunConfig
    pipeline: Pipeline
    plan: dict[str, Any] = field(default_factory=dict)

    @cached_property
    def reader(self) -> LogReader:
        """The log reader of the run's data source, opened as the run recorded it."""
        return self.run.open_log()

    @cached_property
    def frames(self):
        """The frame table of this sequence (pyarrow Table), written by the ``ingest`` stage (every
        stage may read it: every pipeline starts with ingest)."""
        return self.store.read_table(self.sequence, self.pipeline["ingest"].table("frames"))

    def manifest(self, stage: str) -> Manifest:
        """The manifest of another stage of this sequence. Raises StoreError when it has none."""
        m = self.store.read_manifest(self.sequence, stage)
        if m is None:
            raise StoreError(self.store.where(self.sequence, stage), f"stage {stage!r} has not run")
        return m

    def _declared(self, stage: str) -> None:
        """Raise StoreError unless this stage declares that it reads ``stage`` (:meth:`Stage.sources`)."""
        if stage != self.stage and stage not in self.pipeline[self.stage].sources(self.pipeline):
            raise StoreError(
                self.store.where(self.sequence, self.stage),
                f"stage {self.stage!r} reads stage {stage!r} without declaring it (upstream or reads())",
            )

    def arrays(self, stage: str, read_only: bool = True) -> StageArrays:
        """The zarr arrays of a stage of this sequence, by its declaration in the pipeline (a stage
        it declares it reads, or itself)."""
        self._declared(stage)
        return self.store.arrays(self.sequence, self.pipeline[stage].contract, read_only)

    def table(self, stage: str, name: str):
        """One of a stage's tables, this sequence's partition (pyarrow Table); as :meth:`arrays`."""
        self._declared(stage)
        return self.store.read_table(self.sequence, self.pipeline[stage].table(name))

    def frame_values(self) -> FrameValues:
        """Per-frame values of this stage's volume sources (:class:`tasks.frames.FrameValues`), the
        mapping found by declaration upstream of this stage (which must declare it reads it)."""
        from tasks.frames import FrameValues

        values = FrameValues.near(self.store, self.pipeline, self.sequence, self.stage)
        if values.mapping is not None:
            self._declared(values.mapping)
        return values

    @cached_property
    def label_map(self) -> LabelMap:
        """The label map of the model's predictions: the class map the nearest upstream model stage
        recorded from its checkpoint card (see :data:`CLASS_MAP`).

        Raises:
            StoreError: no upstream stage recorded a class map.
        """
        from dsnet_core.labels import label_map_from_class_map

        for stage in reversed(self.pipeline.upstream_closure(self.stage)):
            m = self.store.read_manifest(self.sequence, stage)
            if m is not None and CLASS_MAP in m.plan:
                return label_map_from_class_map(m.plan[CLASS_MAP])
        raise StoreError(
            self.store.where(self.sequence, self.stage), "no upstream model stage recorded a class map"
        )


STATE_SHARE = 0.05
"""Most of a stage's time that writing its resume state may take (``stitch``, ``track``): the
state holds every track so far, so writing it after every item costs O(n) per item and O(n²) per
sequence; past that share it is written less often (a resume replays a few more items, with the
same result)."""


class StateThrottle:
    """``due()`` once the time since the last timed block (``with throttle:``) is at least that
    block's duration / ``share``; always before the first."""

    def __init__(self, share: float = STATE_SHARE, clock=time.perf_counter) -> None:
        self.share, self.clock, self.cost, self.since = share, clock, 0.0, clock()

    def due(self) -> bool:
        return (self.clock() - self.since) * self.share >= self.cost

    def __enter__(self) -> None:
        self._t0 = self.clock()

    def __exit__(self, *exc) -> None:
        self.since = self.clock()
        self.cost = self.since - self._t0
