"""The plain runner (:mod:`tasks.runner`) for run configs written by hand.

The runner takes only a typed :class:`~tasks.run_config.RunConfig`. Tests and benchmarks write
their run configs as dicts (what ``store.write_run_config`` records); these wrappers are their
boundary: each converts the dict once (:meth:`RunConfig.of`) and calls the typed runner. The
other names are the runner's own.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from storage.manifest import Manifest
from storage.run import RunStore
from tasks import runner
from tasks.base import StageContext
from tasks.pipeline import Pipeline
from tasks.run_config import RunConfig
from tasks.runner import ITEM_LISTENERS, BlockJob, Decision, finalize_stage, run_block

__all__ = [
    "ITEM_LISTENERS",
    "BlockJob",
    "Decision",
    "finalize_stage",
    "make_context",
    "prepare_stage",
    "run_block",
    "run_stage_plain",
    "stage_fingerprint",
    "stage_state",
]

Run = RunConfig | Mapping[str, Any]
"""A run config, or a hand-written dict of one."""


def run_stage_plain(
    store: RunStore, pipeline: Pipeline, sequence: str, stage: str, run: Run, run_id: str, force: bool = False
) -> Manifest:
    return runner.run_stage_plain(store, pipeline, sequence, stage, RunConfig.of(run), run_id, force)


def prepare_stage(
    store: RunStore, pipeline: Pipeline, sequence: str, stage: str, run: Run, run_id: str, force: bool = False
) -> Decision:
    return runner.prepare_stage(store, pipeline, sequence, stage, RunConfig.of(run), run_id, force)


def make_context(
    store: RunStore, pipeline: Pipeline, sequence: str, stage: str, run: Run, plan: dict | None = None
) -> StageContext:
    return runner.make_context(store, pipeline, sequence, stage, RunConfig.of(run), plan)


def stage_fingerprint(store: RunStore, pipeline: Pipeline, sequence: str, stage: str, run: Run) -> str:
    return runner.stage_fingerprint(store, pipeline, sequence, stage, RunConfig.of(run))


def stage_state(
    store: RunStore, pipeline: Pipeline, sequence: str, stage: str, run: Run | None = None, full: bool = False
) -> tuple[str, Manifest | None, int]:
    return runner.stage_state(
        store, pipeline, sequence, stage, None if run is None else RunConfig.of(run), full
    )
