"""Flows ``label-sequence`` and ``label-dataset``: run a method's stages in order over sequences.

:func:`label` reads like the run: validate the request, record the run, lock, run each stage
(:mod:`flows.stage_loop`), report, publish. Sequences run in parallel through the task runner
(threads by default, Dask with ``task_runner=``); a stage starts for all sequences once the
previous one finished for all.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Iterator
from typing import Any

from prefect import flow, get_run_logger

from flows.request import LabelRequest
from flows.run_record import check_same_log, new_run_id, record_run, report_run
from flows.stage_loop import RunState, run_stage
from storage.errors import StoreError
from storage.locks import LockSet, Owner
from storage.run import RunStore
from tasks.pipeline import Pipeline
from tasks.score import ScoreStage


def label(request: LabelRequest, isolate: bool = False) -> list[dict[str, Any]]:
    """The body of both flows. Returns one summary row per (sequence, stage), plus one per failed
    sequence. With ``isolate`` a sequence that fails leaves the run and the others go on (the
    scheduled tick's policy: its bad files are tried again next time, not quarantined)."""
    pipeline = request.pipeline()
    reader = request.open_log()
    sequences = request.sequences if request.sequences is not None else reader.sequences()
    store = RunStore(request.root, request.storage_options)
    check_same_log(store, request)
    run_id = new_run_id()
    state = RunState(run_id, request.order(pipeline), request.options, log=get_run_logger(), isolate=isolate)
    forced = request.forced(pipeline)
    with stage_locks(store, pipeline, state.stages, sequences, run_id, request):
        run = record_run(store, run_id, request, pipeline, reader.format, sequences)  # lock winners only
        state.log.info(
            "run %s: %d sequences, stages %s, store %s", run_id, len(sequences), state.stages, store.uri
        )
        for stage in state.stages:
            run_stage(store, pipeline, stage, sequences, run, state, force=stage in forced)
        summary = state.rows()
        report_run(store, run_id, summary)
        if ScoreStage.name in state.stages or pipeline.labels in state.stages:  # report, dashboard, artifacts
            _publish(request, pipeline, state.log)  # still under the locks: another run waits
    return summary


def _publish(request: LabelRequest, pipeline: Pipeline, log) -> None:
    """The report tables, dashboard and artifacts. A store another run is changing (sequences this
    run did not lock) leaves the report as it was, with a warning: the run's labels are done."""
    from flows.publish import publish

    try:
        publish(
            request.root, request.dataset_name(), storage_options=request.storage_options, pipeline=pipeline
        )
    except StoreError as exc:
        log.warning("the report was not refreshed (%s); `dsnet dashboard %s` rebuilds it", exc, request.root)


@contextlib.contextmanager
def stage_locks(
    store: RunStore,
    pipeline: Pipeline,
    order: list[str],
    sequences: list[str],
    run_id: str,
    request: LabelRequest,
) -> Iterator[LockSet]:
    """Hold the lock of every (sequence, stage) the run may write or clear — ``until`` does not stop
    the clearing of downstream stages — taken in one fixed order so two runs cannot deadlock."""
    opts = request.options
    locks = LockSet(store.root, Owner(run_id), opts.lock_wait_s, opts.stale_after_s, opts.heartbeat_s)
    touched = [
        s for s in pipeline.names() if s in order or any(s in pipeline.downstream_of(o) for o in order)
    ]
    try:
        for seq in sequences:
            for stage in touched:
                locks.acquire(store.lock_rel(seq, stage))
        yield locks
    finally:
        locks.release_all()


def _request(request: LabelRequest | dict[str, Any]) -> LabelRequest:
    return request if isinstance(request, LabelRequest) else LabelRequest.model_validate(request)


@flow(name="label-sequence", persist_result=False, validate_parameters=False)
def label_sequence(request: LabelRequest | dict[str, Any], sequence: str) -> list[dict[str, Any]]:
    """Label one sequence: every stage (or up to ``until``), skipping what the store already holds."""
    return label(_request(request).model_copy(update={"sequences": [sequence]}))


@flow(name="label-dataset", persist_result=False, validate_parameters=False)
def label_dataset(request: LabelRequest | dict[str, Any]) -> list[dict[str, Any]]:
    """Label several sequences in parallel (all of the log when ``sequences`` is None), up to ``until``."""
    return label(_request(request))


def task_runner(workers: int | None = None, dask_address: str | None = None):
    """Threads by default; a Dask cluster (existing address, or a local one of N workers) on request."""
    if dask_address or workers:
        from prefect_dask import DaskTaskRunner

        logging.getLogger("distributed").setLevel(logging.WARNING)
        if dask_address:
            from flows.services import check_dask_scheduler

            check_dask_scheduler(dask_address)  # once more: the check may have run minutes ago
            return DaskTaskRunner(address=dask_address)
        return DaskTaskRunner(  # scheduler and dashboard on loopback: nothing listens on 0.0.0.0
            cluster_kwargs={
                "n_workers": workers,
                "threads_per_worker": 1,
                "processes": True,
                "host": "127.0.0.1",
                "dashboard_address": "127.0.0.1:8787",
            }
        )
    from prefect.task_runners import ThreadPoolTaskRunner

    return ThreadPoolTaskRunner(max_workers=4)
