"""One stage of a labelling run over every sequence: decide, submit the blocks, finalise.

Per stage: decide skip / resume / fresh for every sequence (the manifest decides, not Prefect's
cache), submit one task per (sequence, stage, block) to the task runner, wait for all of them,
then finalise each sequence's stage. The error policy (``fail`` or ``skip``) is applied here: with
``skip`` (or a run that isolates its sequences, as a scheduled tick does) a sequence that fails
leaves the run and the others go on.
"""

from __future__ import annotations

import contextlib
import logging
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

from prefect import task
from prefect.artifacts import create_progress_artifact, update_progress_artifact
from prefect.cache_policies import NO_CACHE
from prefect.futures import as_completed

from dsnet_core.errors import DataFormatError
from flows.progress import BlockEvent, emit
from storage.errors import StoreError, as_write_error
from storage.run import RunStore
from tasks.base import RunOptions
from tasks.pipeline import Pipeline
from tasks.run_config import RunConfig
from tasks.runner import BlockJob, Decision, finalize_stage, mark_failed, prepare_stage, run_block


def _transient(task, task_run, state) -> bool:
    """Retry storage hiccups (I/O, timeouts), never bad data or store/lock errors."""
    exc = state.result(raise_on_failure=False)
    if isinstance(exc, DataFormatError | StoreError | FileNotFoundError | PermissionError):
        return False
    return isinstance(exc, OSError | TimeoutError | ConnectionError)


@task(
    name="stage-block",
    task_run_name="{job.stage}-{job.sequence}-b{job.block}",
    cache_policy=NO_CACHE,
    persist_result=False,
    retries=2,
    retry_delay_seconds=[1, 8],  # backoff: a throttled bucket gets time to recover
    retry_condition_fn=_transient,
)
def block_task(job: BlockJob) -> dict[str, Any]:
    """One (sequence, stage, block): compute and store; returns a small dict."""
    where = RunStore(job.root, job.storage_options).where(job.sequence, job.stage)
    with store_writes(where):
        return run_block(job)


@contextlib.contextmanager
def store_writes(where: str) -> Iterator[None]:
    """Turn an OSError of a full, read-only or forbidden store into a :class:`StoreWriteError` naming
    the file (or ``where``): typed, one line, and not retried like a transient hiccup."""
    try:
        yield
    except OSError as exc:
        typed = as_write_error(exc, where)
        if typed is None:
            raise
        raise typed from exc


@dataclass
class RunState:
    """What a run has done so far: the summary rows, the failed sequences and the progress artifact.

    Attributes:
        run_id: the run.
        stages: the stages the run executes (for progress).
        options: the error policy.
        summary: one row per (sequence, stage).
        failed: sequence -> "stage: error" of sequences that left the run.
        isolate: a sequence that fails leaves the run and the others go on, whatever the error
            policy (its frames are not quarantined: the next run tries it again).
    """

    run_id: str
    stages: list[str]
    options: RunOptions
    summary: list[dict[str, Any]] = field(default_factory=list)
    failed: dict[str, str] = field(default_factory=dict)
    progress_id: Any = None
    log: Any = None
    isolate: bool = False

    def __post_init__(self) -> None:
        self.progress_id = create_progress_artifact(
            0.0, key="label-progress", description=f"run {self.run_id}"
        )
        self.log = self.log or logging.getLogger(__name__)

    def fail(self, sequence: str, stage: str, exc: BaseException) -> None:
        if sequence not in self.failed:
            self.log.error("sequence %s failed in %s: %s", sequence, stage, exc)
            self.failed[sequence] = f"{stage}: {exc}"

    def progress(self, stage: str, fraction: float) -> None:
        done = self.stages.index(stage) + fraction
        update_progress_artifact(self.progress_id, 100.0 * done / len(self.stages))

    def rows(self) -> list[dict[str, Any]]:
        """The summary, with one ``failed`` row per sequence that left the run."""
        failed = [
            {"sequence": s, "stage": "-", "action": "failed", "error": e} for s, e in self.failed.items()
        ]
        return self.summary + failed


def run_stage(
    store: RunStore,
    pipeline: Pipeline,
    stage: str,
    sequences: list[str],
    run: RunConfig,
    state: RunState,
    force: bool,
) -> None:
    """Run one stage for every sequence still in the run.

    Raises:
        The first block's error when the policy is ``fail`` (after every block of the stage settled,
        so nothing writes after the locks are released).
    """
    t0 = time.perf_counter()
    skip = state.options.on_error == "skip" or state.isolate
    decisions: dict[str, Decision] = {}
    for seq in sequences:
        if seq in state.failed:
            continue
        try:
            with store_writes(store.where(seq, stage)):
                decisions[seq] = prepare_stage(store, pipeline, seq, stage, run, state.run_id, force=force)
        except (DataFormatError, StoreError) as exc:
            if not skip:
                raise
            state.fail(seq, stage, exc)
    jobs = [j for d in decisions.values() for j in d.jobs]
    unit = f"{pipeline[stage].item}s"
    total = sum(len(j.items) for j in jobs)
    futures = {block_task.submit(j): j for j in jobs}
    errors: list[BaseException] = []
    emit(BlockEvent(stage, 0, total, unit=unit))
    items = 0
    for done, fut in enumerate(as_completed(list(futures)), start=1):
        job = futures[fut]
        items += len(job.items)
        try:
            fut.result()
        except Exception as exc:
            mark_failed(store, job.sequence, stage, job.fingerprint, repr(exc))
            state.fail(job.sequence, stage, exc)
            if not skip:
                errors.append(exc)
        emit(BlockEvent(stage, items, total, job.sequence, unit))
        state.progress(stage, done / max(len(jobs), 1))
    if errors:
        raise errors[0]
    for seq, d in decisions.items():
        if seq in state.failed:
            continue
        with store_writes(store.where(seq, stage)):
            m = (
                d.manifest
                if d.action == "skip"
                else finalize_stage(store, pipeline, seq, stage, d.fingerprint)
            )
        state.summary.append(
            {
                "sequence": seq,
                "stage": stage,
                "action": d.action,
                "blocks_run": len(d.jobs),
                "blocks": len(m.blocks),
                "items": m.n_items,
                "points": m.counts.get("points", 0),
                "fingerprint": m.fingerprint,
                "seconds": round(time.perf_counter() - t0, 3) if d.jobs else 0.0,
            }
        )
    state.progress(stage, 1.0)
