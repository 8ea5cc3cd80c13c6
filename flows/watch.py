"""Scheduled auto-labelling: flow ``auto-label`` and the deployment ``dsnet serve`` serves.

On each tick: find the sequences of the watched log that are new or stale (the manifests decide:
no finished ingest, changed source files, or a stage not done / done with another config or
upstream), label them with every stage that exists, score where ground truth exists, refresh the
report tables, the dashboard and the artifacts (:mod:`flows.publish`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from prefect import flow, get_run_logger
from prefect.artifacts import create_markdown_artifact

from flows.label import label
from flows.publish import dataset_key, publish
from flows.request import LabelRequest
from storage.errors import StoreError
from storage.run import RunStore
from tasks.run_config import RunConfig
from tasks.runner import stage_fingerprint, stage_state


def pending_sequences(request: LabelRequest) -> list[str]:
    """Sequences of the request's log that its store lacks or holds stale (in the stages the request
    runs: all, or up to ``until``). The manifests decide: no finished ingest, changed source files,
    or a stage not done / done with another config or upstream."""
    pipeline = request.pipeline()
    order = request.order(pipeline)
    first = order[0]
    store = RunStore(request.root, request.storage_options)
    reader = request.open_log()
    run = RunConfig(
        data=str(request.data),
        format=reader.format,
        reader_options=dict(request.reader_options),
        stages=request.stage_configs(pipeline),
    )
    out = []
    for seq in reader.sequences():
        m = store.read_manifest(seq, first)
        if m is None or m.status != "done":
            out.append(seq)
            continue
        if stage_fingerprint(store, pipeline, seq, first, run) != m.fingerprint or any(
            stage_state(store, pipeline, seq, s, run)[0] != "done" for s in order
        ):
            out.append(seq)
    return out


@flow(name="auto-label", persist_result=False, validate_parameters=False)
def auto_label(request: LabelRequest | dict[str, Any], dataset: str | None = None) -> dict[str, Any]:
    """One tick: label new or stale sequences of the request's log into its store (every stage, or up
    to ``until``), score, publish."""
    logger = get_run_logger()
    request = request if isinstance(request, LabelRequest) else LabelRequest.model_validate(request)
    name = dataset or request.dataset_name()
    pending = pending_sequences(request)
    logger.info("%d sequence(s) new or stale in %s: %s", len(pending), request.data, pending)
    summary = label(request.model_copy(update={"sequences": pending})) if pending else []
    try:
        published = publish(request.root, name, storage_options=request.storage_options)
    except StoreError as exc:  # an empty store (nothing ever labelled)
        logger.info("nothing to publish: %s", exc)
        published = {"scored": False, "dashboard": None, "headline": {}}
    lines = [
        f"# Auto-label tick · {name}",
        "",
        f"Watched log: `{request.data}` · run store: `{request.root}`",
        "",
        f"Labelled {len(pending)} sequence(s): {', '.join(pending) or 'none (everything up to date)'}",
        f"Stages: {', '.join(request.order(request.pipeline()))}",
        "",
    ]
    if published["scored"]:
        h = published["headline"]
        lines.append(
            f"PQ {100 * h['pq']:.1f} · mIoU {100 * h['miou']:.1f} · frames {h['frames']} ({h['mode']})"
        )
        lines.append(f"Dashboard: `{published['dashboard']}`")
    else:
        lines.append("No scores: no ground truth or no score stage in this pipeline yet.")
    create_markdown_artifact("\n".join(lines), key=f"auto-label-{dataset_key(name)}", description=name)
    failed = [r["sequence"] for r in summary if r.get("action") == "failed"]
    return {"labelled": pending, "failed": failed, **published}


def serve(
    request: LabelRequest,
    cron: str,
    name: str | None = None,
    say: Callable[[str], None] = print,
    check_every_s: float = 30.0,
    grace_s: float = 150.0,
) -> None:
    """Serve ``auto-label`` as a deployment with a cron schedule (blocks; needs a Prefect server).

    While serving, :class:`~flows.schedule_watch.ScheduleWatch` reports through ``say`` when the
    server schedules no runs, a run is late, or a run fails.
    """
    from flows.schedule_watch import ScheduleWatch

    dataset = name or request.dataset_name()
    request.order(request.pipeline())  # an unknown method or stage fails here, not at the first tick
    deployment = f"auto-label-{dataset_key(dataset)}"
    watch = ScheduleWatch(f"auto-label/{deployment}", say, every_s=check_every_s, grace_s=grace_s).start()
    try:
        _serve(request, cron, dataset, deployment)
    finally:
        watch.stop()


def _serve(request: LabelRequest, cron: str, dataset: str, deployment: str) -> None:
    auto_label.serve(
        name=deployment,
        cron=cron,
        parameters={"request": request.model_dump(mode="json"), "dataset": dataset},
        description=f"Label new or stale sequences of {request.data} into {request.root}, score, refresh "
        "the dashboard.",
        print_starting_message=False,
    )
