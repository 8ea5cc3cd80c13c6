"""A run's record in its store (config, code version, summary) and its Prefect summary artifacts."""

from __future__ import annotations

import socket
import time
import uuid
from pathlib import Path
from typing import Any

from prefect.artifacts import create_markdown_artifact, create_table_artifact

from dsnet_core.version import code_version
from flows.config import CONFIG_FILE, resolved_config
from flows.request import LabelRequest
from storage.errors import NoRunConfigError, StoreError
from storage.run import RunStore
from tasks.pipeline import Pipeline
from tasks.run_config import RunConfig, read_run

SUMMARY_COLUMNS = ("sequence", "stage", "action", "blocks_run", "items", "points", "seconds", "fingerprint")


def new_run_id() -> str:
    """``<UTC-less local time>-<6 hex>``: sortable by start, unique across concurrent runs."""
    return f"{time.strftime('%Y%m%dT%H%M%S')}-{uuid.uuid4().hex[:6]}"


def check_same_log(store: RunStore, request: LabelRequest) -> None:
    """Refuse a run store that already holds the runs of another log: its tables, report and
    dashboard would mix the two logs' sequences (a store is one log's, labelled any number of times).

    Raises:
        StoreError: naming the store, the log it holds and the one requested.
    """
    try:
        previous = read_run(store)
    except NoRunConfigError:
        return  # a new store
    if _same_place(previous.data, request.data):
        return
    raise StoreError(
        store.uri,
        f"holds runs of the log {previous.data}, not {request.data}: give this log its own --run "
        "folder (or remove this one)",
    )


def _same_place(a: str | None, b: str) -> bool:
    if not a or a == b:
        return True
    if "://" in a or "://" in b:
        return a.rstrip("/") == b.rstrip("/")
    return Path(a).resolve() == Path(b).resolve()


def record_run(
    store: RunStore,
    run_id: str,
    request: LabelRequest,
    pipeline: Pipeline,
    log_format: str,
    sequences: list[str],
) -> RunConfig:
    """Write the run's config to the store (``run.json`` and ``runs/<id>.json``, and the resolved
    config ``dsnet label --config`` takes back, ``config.yaml``: :func:`~flows.config.resolved_config`)
    and return it; the caller holds the run's locks, so a run that lost them never rewrites them.

    The config holds what every stage reads back: the log, its format and reader options, the method
    and each executed stage's settings (:meth:`~flows.request.LabelRequest.stage_configs`), and the
    run options.
    """
    run = request.run_config(
        pipeline,
        log_format,
        sequences,
        run_id=run_id,
        code_version=code_version(),
        host=socket.gethostname(),
        started=time.time(),
    )
    store.write_run_config(run_id, run.model_dump(mode="json", exclude_none=True))
    resolved = resolved_config(request, pipeline, log_format, sequences)
    store.root.write_bytes(CONFIG_FILE, resolved.to_yaml().encode())
    return run


def report_run(store: RunStore, run_id: str, summary: list[dict[str, Any]]) -> None:
    """The run's summary: into its record in the store, and as table + markdown artifacts."""
    store.update_run_record(run_id, finished=time.time(), summary=summary)
    rows = [{k: r.get(k, "") for k in SUMMARY_COLUMNS} for r in summary]
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
