"""Scheduled auto-labelling: flow ``auto-label`` and the deployment ``dsnet serve`` serves.

On each tick: find the sequences of the watched log that are new or stale (the manifests decide:
no finished ingest, changed source files, or a stage not done / done with another config or
upstream), label them with every stage that exists, score where ground truth exists, refresh the
report tables, the dashboard and the artifacts (:mod:`flows.publish`).
"""

from __future__ import annotations

import posixpath
from typing import Any

from prefect import flow, get_run_logger
from prefect.artifacts import create_markdown_artifact

from flows.label import label
from flows.publish import dataset_key, publish
from storage.errors import StoreError
from storage.manifest import fingerprint
from storage.run import RunStore
from tasks.registry import STAGES, stage_order
from tasks.runner import make_context, resolved_config, stage_state


def pipeline(until: str | None = None) -> list[str]:
    """The stages a tick runs: all, or up to ``until``."""
    order = stage_order()
    if until is not None and until not in order:
        raise ValueError(f"unknown stage {until!r}; stages are {order}")
    return order if until is None else order[: order.index(until) + 1]


def pending_sequences(
    data: str, root: str, stages: dict[str, dict] | None = None, until: str | None = None
) -> list[str]:
    """Sequences of the log at ``data`` that the store at ``root`` lacks or holds stale (in the
    stages up to ``until``)."""
    from dsnet_core.io.formats import open_log

    store = RunStore(root)
    reader = open_log(data)
    run = {
        "data": str(data),
        "format": reader.format,
        "stages": {n: dict((stages or {}).get(n, {})) for n in stage_order()},
    }
    out = []
    for seq in reader.sequences():
        m = store.read_manifest(seq, "ingest")
        if m is None or m.status != "done":
            out.append(seq)
            continue
        ingest = STAGES["ingest"]
        ctx = make_context(store, seq, "ingest", run)
        fp = fingerprint("ingest", ingest.version, resolved_config("ingest", run), {}, ingest.inputs(ctx))
        if fp != m.fingerprint or any(stage_state(store, seq, s, run)[0] != "done" for s in pipeline(until)):
            out.append(seq)
    return out


@flow(name="auto-label", persist_result=False, validate_parameters=False)
def auto_label(
    data: str,
    runs: str,
    stages: dict[str, dict] | None = None,
    options: dict[str, Any] | None = None,
    dataset: str | None = None,
    until: str | None = None,
) -> dict[str, Any]:
    """One tick: label new or stale sequences of ``data`` into the store ``runs`` (every stage, or
    up to ``until``), score, publish."""
    logger = get_run_logger()
    name = dataset or posixpath.basename(str(data).rstrip("/"))
    pending = pending_sequences(data, runs, stages, until)
    logger.info("%d sequence(s) new or stale in %s: %s", len(pending), data, pending)
    summary = label(data, runs, pending, stages, options, until=until) if pending else []
    try:
        published = publish(runs, name)
    except StoreError as exc:  # an empty store (nothing ever labelled)
        logger.info("nothing to publish: %s", exc)
        published = {"scored": False, "dashboard": None, "headline": {}}
    lines = [
        f"# Auto-label tick · {name}",
        "",
        f"Watched log: `{data}` · run store: `{runs}`",
        "",
        f"Labelled {len(pending)} sequence(s): {', '.join(pending) or 'none (everything up to date)'}",
        f"Stages: {', '.join(pipeline(until))}",
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
    data: str,
    runs: str,
    cron: str,
    name: str | None = None,
    stages: dict | None = None,
    until: str | None = None,
) -> None:
    """Serve ``auto-label`` as a deployment with a cron schedule (blocks; needs a Prefect server)."""
    dataset = name or posixpath.basename(str(data).rstrip("/"))
    pipeline(until)  # an unknown stage fails here, not at the first tick
    auto_label.serve(
        name=f"auto-label-{dataset_key(dataset)}",
        cron=cron,
        parameters={
            "data": str(data),
            "runs": str(runs),
            "stages": stages or {},
            "dataset": dataset,
            "until": until,
        },
        description=f"Label new or stale sequences of {data} into {runs}, score, refresh the dashboard.",
        print_starting_message=False,
    )
