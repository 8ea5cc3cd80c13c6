"""What a stage declares to plug into the pipeline, and the context its block function gets.

A stage is a class with a ``name``, ``upstream`` stages, a ``version`` (bump it when the output
changes), a pydantic ``Config``, a contract in :mod:`storage.contract`, and two functions:
``plan`` (how many items, how big) and ``run_block`` (store -> dsnet_core -> yielded item results).
The shared runner (:mod:`tasks.runner`) does everything else: fingerprints, skip/resume/clear,
writing arrays with ``done`` last, block fragments, tables and the manifest.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Iterator
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any, ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict

from storage.contract import CONTRACTS, StageContract
from storage.run import RunStore


class StageConfig(BaseModel):
    """Base of every stage config: frozen, unknown keys rejected."""

    model_config = ConfigDict(frozen=True, extra="forbid")


class RunOptions(BaseModel):
    """Run-level policy. Not part of any fingerprint: it does not change what a finished stage holds."""

    model_config = ConfigDict(extra="forbid")

    on_error: str = "fail"  # "fail" | "skip" (quarantine bad frames)
    block_size: int = 25  # items per task
    lock_wait_s: float = 0.0  # how long a second run waits for a held lock
    stale_after_s: float = 60.0  # heartbeat age after which a lock is abandoned
    heartbeat_s: float = 5.0


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
    """

    n_items: int
    max_points: int = 0
    omit: tuple[str, ...] = ()
    meta: dict[str, Any] = field(default_factory=dict)
    blocks: list[list[int]] | None = None


@dataclass
class ItemResult:
    """One item's output. ``arrays`` must match the contract; ``rows`` are table rows by table name."""

    index: int
    arrays: dict[str, np.ndarray] = field(default_factory=dict)
    n_points: int = 0
    rows: dict[str, list[dict[str, Any]]] = field(default_factory=dict)
    counts: dict[str, int] = field(default_factory=dict)


@dataclass
class StageContext:
    """Everything a stage function may read. Built by the runner, in any process (threads, Dask)."""

    store: RunStore
    sequence: str
    config: Any
    run: dict[str, Any]
    options: RunOptions
    plan: dict[str, Any] = field(default_factory=dict)

    @cached_property
    def reader(self):
        """The log reader of the run's data source, opened as the run recorded it."""
        from dsnet_core.io.formats import open_log

        return open_log(self.run["data"], self.run.get("format", "auto"), self.run.get("reader_options"))

    @cached_property
    def frames(self):
        """The ingest frame table of this sequence (pyarrow Table)."""
        return self.store.read_table(self.sequence, "ingest", "frames")


class Stage(ABC):
    """A pipeline stage. Subclasses set the class attributes and implement plan/run_block."""

    name: ClassVar[str]
    upstream: ClassVar[tuple[str, ...]] = ()
    version: ClassVar[str]
    Config: ClassVar[type[StageConfig]] = StageConfig

    @property
    def contract(self) -> StageContract:
        return CONTRACTS[self.name]

    def inputs(self, ctx: StageContext) -> str:
        """Digest of inputs from outside the store (cheap: sizes and times, not content)."""
        return ""

    @abstractmethod
    def plan(self, ctx: StageContext) -> Plan:
        """Items and sizes for one sequence (runs once per fresh stage run)."""

    @abstractmethod
    def run_block(self, ctx: StageContext, items: list[int]) -> Iterator[ItemResult]:
        """Compute the given items, yielding one result per item (the runner writes them)."""
