"""Flows ``label-sequence`` and ``label-dataset``: run the stages in order over sequences.

Per stage: decide skip / resume / fresh for every sequence (the manifest decides, not Prefect's
cache), submit one task per (sequence, stage, block) to the task runner, then finalise each
sequence's stage. Sequences run in parallel through the task runner (threads by default, Dask with
``task_runner=``); a stage starts for all sequences once the previous one finished for all.
"""

from __future__ import annotations

import logging
import socket
import subprocess
import time
import uuid
from pathlib import Path
from typing import Any

from prefect import flow, get_run_logger, task
from prefect.artifacts import (
    create_markdown_artifact,
    create_progress_artifact,
    create_table_artifact,
    update_progress_artifact,
)
from prefect.cache_policies import NO_CACHE
from prefect.futures import as_completed

from dsnet_core.errors import DataFormatError
from flows.progress import BlockEvent, emit
from storage.errors import StoreError
from storage.locks import LockSet, Owner
from storage.run import RunStore
from tasks.base import RunOptions
from tasks.registry import STAGES, downstream_of, stage_order
from tasks.runner import BlockJob, finalize_stage, mark_failed, prepare_stage, run_block


def code_version() -> str:
    """Package version and, in a git checkout, the commit (recorded in the run config; fingerprints
    use each stage's own ``version`` so an unrelated commit does not invalidate finished stages)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        out = f"dsnet-pipeline {version('dsnet-pipeline')}"
    except PackageNotFoundError:
        out = "dsnet-pipeline (not installed)"
    repo = Path(__file__).resolve().parents[1]
    if (repo / ".git").exists():
        try:
            res = subprocess.run(
                ["git", "rev-parse", "--short", "HEAD"], cwd=repo, capture_output=True, text=True, timeout=5
            )
            if res.returncode == 0:
                out += f" git {res.stdout.strip()}"
        except (OSError, subprocess.TimeoutExpired):
            pass
    return out


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
    retry_delay_seconds=1,
    retry_condition_fn=_transient,
)
def block_task(job: BlockJob) -> dict[str, Any]:
    """One (sequence, stage, block): compute and store; returns a small dict."""
    return run_block(job)


def _lock_rel(store: RunStore, sequence: str, stage: str) -> str:
    return f"{store.stage_rel(sequence, stage)}/lock.json"


def label(
    data: str,
    root: str,
    sequences: list[str] | None = None,
    stages: dict[str, dict] | None = None,
    options: dict[str, Any] | None = None,
    from_stage: str | None = None,
    force: bool = False,
    storage_options: dict[str, Any] | None = None,
    until: str | None = None,
    format: str = "auto",
) -> list[dict[str, Any]]:
    """The body of both flows. Returns one summary row per (sequence, stage).

    ``until`` stops after that stage (default: run every stage).
    """
    logger = get_run_logger()
    store = RunStore(root, storage_options)
    opts = RunOptions.model_validate(options or {})
    order = stage_order()
    for name in (from_stage, until):
        if name is not None and name not in order:
            raise ValueError(f"unknown stage {name!r}; stages are {order}")
    if until is not None:
        order = order[: order.index(until) + 1]
    forced = set(order) if force else ({from_stage, *downstream_of(from_stage)} if from_stage else set())
    from dsnet_core.io.formats import open_log

    reader = open_log(data, format)
    if sequences is None:
        sequences = reader.sequences()
    run_id = f"{time.strftime('%Y%m%dT%H%M%S')}-{uuid.uuid4().hex[:6]}"
    run = {
        "code_version": code_version(),
        "stage_versions": {name: STAGES[name].version for name in order},
        "data": str(data),
        "format": reader.format,
        "sequences": list(sequences),
        "stages": {name: dict((stages or {}).get(name, {})) for name in order},
        "options": opts.model_dump(),
        "host": socket.gethostname(),
        "started": time.time(),
    }
    store.write_run_config(run_id, run)
    logger.info("run %s: %d sequences, stages %s, store %s", run_id, len(sequences), order, store.uri)

    locks = LockSet(store.root, Owner(run_id), opts.lock_wait_s, opts.stale_after_s, opts.heartbeat_s)
    summary: list[dict[str, Any]] = []
    failed: dict[str, str] = {}
    errors: list[BaseException] = []
    progress_id = create_progress_artifact(0.0, key="label-progress", description=f"run {run_id}")
    total_stages = len(order)
    try:
        # every stage this run may write or clear (``until`` does not stop the clearing of downstream
        # stages), in one fixed order so two runs cannot deadlock
        lock_stages = [s for s in stage_order() if s in order or any(s in downstream_of(o) for o in order)]
        for seq in sequences:
            for stage in lock_stages:
                locks.acquire(_lock_rel(store, seq, stage))
        for s_idx, stage in enumerate(order):
            t0 = time.perf_counter()
            decisions = {}
            for seq in sequences:
                if seq in failed:
                    continue
                try:
                    decisions[seq] = prepare_stage(store, seq, stage, run, run_id, force=stage in forced)
                except (DataFormatError, StoreError) as exc:
                    if opts.on_error != "skip":
                        raise
                    _fail(failed, seq, stage, exc, opts, logger)
            jobs = [j for d in decisions.values() for j in d.jobs]
            futures = {block_task.submit(j): j for j in jobs}
            done = 0
            emit(BlockEvent(stage, 0, len(jobs)))
            for fut in as_completed(list(futures)):
                job = futures[fut]
                try:
                    fut.result()
                except Exception as exc:
                    mark_failed(store, job.sequence, stage, job.fingerprint, repr(exc))
                    _fail(failed, job.sequence, stage, exc, opts, logger)
                    if opts.on_error != "skip":
                        errors.append(exc)
                done += 1
                emit(BlockEvent(stage, done, len(jobs), job.sequence))
                update_progress_artifact(
                    progress_id, 100.0 * (s_idx + done / max(len(jobs), 1)) / total_stages
                )
            if errors:  # every block of the stage has settled: nothing writes after the locks go
                raise errors[0]
            for seq, d in decisions.items():
                if seq in failed:
                    continue
                m = d.manifest if d.action == "skip" else finalize_stage(store, seq, stage, d.fingerprint)
                summary.append(
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
            update_progress_artifact(progress_id, 100.0 * (s_idx + 1) / total_stages)
    finally:
        locks.release_all()
    for seq, err in failed.items():
        summary.append({"sequence": seq, "stage": "-", "action": "failed", "error": err})
    _report(run_id, summary)
    store.update_run_record(run_id, finished=time.time(), summary=summary)
    if "score" in order:  # report tables, dashboard and score artifacts (flows/publish.py)
        from flows.publish import publish

        publish(root, str(data).rstrip("/").rsplit("/", 1)[-1], storage_options=storage_options)
    return summary


def _fail(failed: dict[str, str], seq: str, stage: str, exc: BaseException, opts: RunOptions, logger) -> None:
    if seq not in failed:
        logger.error("sequence %s failed in %s: %s", seq, stage, exc)
        failed[seq] = f"{stage}: {exc}"


def _report(run_id: str, summary: list[dict[str, Any]]) -> None:
    rows = [
        {
            k: r.get(k, "")
            for k in (
                "sequence",
                "stage",
                "action",
                "blocks_run",
                "items",
                "points",
                "seconds",
                "fingerprint",
            )
        }
        for r in summary
    ]
    create_table_artifact(rows, key="label-summary", description=f"run {run_id}")
    lines = [
        f"# dsnet label run `{run_id}`",
        "",
        "| sequence | stage | action | blocks run | items | s |",
        "|---|---|---|---|---|---|",
    ]
    for r in summary:
        cells = [r["sequence"], r["stage"], r["action"], r.get("blocks_run", ""), r.get("items", "")]
        lines.append("| " + " | ".join(str(c) for c in [*cells, r.get("seconds", "")]) + " |")
    create_markdown_artifact("\n".join(lines), key="label-report", description=f"run {run_id}")


@flow(name="label-sequence", persist_result=False, validate_parameters=False)
def label_sequence(
    data: str,
    root: str,
    sequence: str,
    stages: dict[str, dict] | None = None,
    options: dict[str, Any] | None = None,
    from_stage: str | None = None,
    force: bool = False,
    storage_options: dict[str, Any] | None = None,
    until: str | None = None,
) -> list[dict[str, Any]]:
    """Label one sequence: every stage (or up to ``until``), skipping what the store already holds."""
    return label(data, root, [sequence], stages, options, from_stage, force, storage_options, until)


@flow(name="label-dataset", persist_result=False, validate_parameters=False)
def label_dataset(
    data: str,
    root: str,
    sequences: list[str] | None = None,
    stages: dict[str, dict] | None = None,
    options: dict[str, Any] | None = None,
    from_stage: str | None = None,
    force: bool = False,
    storage_options: dict[str, Any] | None = None,
    until: str | None = None,
) -> list[dict[str, Any]]:
    """Label several sequences in parallel (all of the log when ``sequences`` is None), up to ``until``."""
    return label(data, root, sequences, stages, options, from_stage, force, storage_options, until)


def task_runner(workers: int | None = None, dask_address: str | None = None):
    """Threads by default; a Dask cluster (existing address, or a local one of N workers) on request."""
    if dask_address or workers:
        from prefect_dask import DaskTaskRunner

        if dask_address:
            return DaskTaskRunner(address=dask_address)
        return DaskTaskRunner(
            cluster_kwargs={"n_workers": workers, "threads_per_worker": 1, "processes": True}
        )
    from prefect.task_runners import ThreadPoolTaskRunner

    return ThreadPoolTaskRunner(max_workers=4)


logging.getLogger("distributed").setLevel(logging.WARNING)
