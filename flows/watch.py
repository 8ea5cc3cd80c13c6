"""Scheduled auto-labelling: flow ``auto-label`` and the deployment ``dsnet serve`` serves.

On each tick: find the sequences of the watched log that are new or stale (the manifests decide:
no finished ingest, changed source files, or a stage not done / done with another config or
upstream), label them with every stage that exists, score where ground truth exists, refresh the
report tables, the dashboard and the artifacts (:mod:`flows.publish`).

A tick labels every healthy sequence: one whose files do not read (a scan still being written, a
pose file cut short) is left out of that tick and reported with its reason, in the tick's
artifact, its log and its final state's message (``dsnet serve`` prints it), and tried again by the
next tick; nothing of it is quarantined. A tick whose watched log is gone ends failed with one line.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from prefect import flow, get_run_logger
from prefect.artifacts import create_markdown_artifact
from prefect.states import Completed, Failed

from dsnet_core.errors import DataFormatError
from flows.label import label
from flows.publish import brief_line, dataset_key, publish
from flows.request import LabelRequest
from storage.errors import StoreError
from storage.run import RunStore
from tasks.runner import stage_fingerprint, stage_state


@dataclass
class Survey:
    """What a tick finds in the watched log.

    Attributes:
        pending: sequences the store lacks or holds stale, in the log's order.
        unreadable: sequence -> why its state could not be told (a file that does not read).
    """

    pending: list[str] = field(default_factory=list)
    unreadable: dict[str, str] = field(default_factory=dict)


def survey(request: LabelRequest) -> Survey:
    """The sequences of the request's log that its store lacks or holds stale (in the stages the
    request runs: all, or up to ``until``). The manifests decide: no finished ingest, changed source
    files, or a stage not done / done with another config or upstream. A sequence whose files cannot
    be read to tell is ``unreadable``, with the reason, and the others are surveyed.

    Raises:
        DataFormatError: the log itself does not open (its folder is gone, nothing detected).
    """
    pipeline = request.pipeline()
    order = request.order(pipeline)
    first = order[0]
    store = RunStore(request.root, request.storage_options)
    reader = request.open_log()
    run = request.run_config(pipeline, reader.format)
    found = Survey()
    for seq in reader.sequences():
        try:
            m = store.read_manifest(seq, first)
            if m is None or m.status != "done":
                found.pending.append(seq)
            elif stage_fingerprint(store, pipeline, seq, first, run) != m.fingerprint or any(
                stage_state(store, pipeline, seq, s, run)[0] != "done" for s in order
            ):
                found.pending.append(seq)
        except (DataFormatError, StoreError, OSError) as exc:  # e.g. a file being replaced right now
            found.unreadable[seq] = str(exc)
    return found


def pending_sequences(request: LabelRequest) -> list[str]:
    """The sequences a tick would label (:func:`survey`'s ``pending``)."""
    return survey(request).pending


@flow(name="auto-label", persist_result=False, validate_parameters=False)
def auto_label(request: LabelRequest | dict[str, Any], dataset: str | None = None) -> Any:
    """One tick: label new or stale sequences of the request's log into its store (every stage, or up
    to ``until``), score, publish.

    Returns:
        ``{"labelled": [...], "failed": [...], "reasons": {seq: why}, **published}``; the run ends
        completed with a message naming the sequences left out (they are tried again next tick),
        or failed with one line when the watched log does not open.
    """
    logger = get_run_logger()
    request = request if isinstance(request, LabelRequest) else LabelRequest.model_validate(request)
    name = dataset or request.dataset_name()
    try:
        found = survey(request)
    except (DataFormatError, StoreError) as exc:  # the watched folder is gone or unreadable
        logger.error("tick failed: %s", exc)
        return Failed(message=f"the watched log does not open: {exc}")
    logger.info("%d sequence(s) new or stale in %s: %s", len(found.pending), request.data, found.pending)
    run = request.model_copy(update={"sequences": found.pending})
    summary = label(run, isolate=True) if found.pending else []
    reasons = dict(found.unreadable)
    reasons.update({r["sequence"]: r["error"] for r in summary if r.get("action") == "failed"})
    labelled = [s for s in found.pending if s not in reasons]
    for seq, why in reasons.items():
        logger.warning("sequence %s not labelled this tick (tried again next tick): %s", seq, why)
    published = _publish(request, name, logger)
    _tick_artifact(request, name, labelled, reasons, published)
    result = {"labelled": labelled, "failed": list(reasons), "reasons": reasons, **published}
    if not reasons:  # the tick's one line (dsnet serve prints it)
        return Completed(message=tick_line(labelled, published), data=result)
    listed = "; ".join(f"{seq}: {why}" for seq, why in reasons.items())
    return Completed(
        message=f"labelled {len(labelled)} sequence(s); not labelled, tried again next tick: {listed}",
        data=result,
    )


def tick_line(labelled: list[str], published: dict[str, Any]) -> str:
    """``labelled 2 sequence(s): 00, 01 · PQ 41.5 · mIoU 37.3`` (or ``nothing new or stale``)."""
    if not labelled:
        return "labelled nothing: nothing new or stale"
    line = f"labelled {len(labelled)} sequence(s): {', '.join(labelled)}"
    h = published.get("headline") or {}
    if published.get("scored") and h.get("pq") is not None:
        line += f" · PQ {100 * h['pq']:.1f} · mIoU {100 * h['miou']:.1f}"
    return line


def _publish(request: LabelRequest, name: str, logger) -> dict[str, Any]:
    try:
        return publish(request.root, name, storage_options=request.storage_options)
    except StoreError as exc:  # an empty store (nothing ever labelled)
        logger.info("nothing to publish: %s", exc)
        return {"scored": False, "dashboard": None, "headline": {}}


def _tick_artifact(
    request: LabelRequest, name: str, labelled: list[str], reasons: dict[str, str], published: dict
) -> None:
    lines = [
        f"# Auto-label tick · {name}",
        "",
        f"Watched log: `{request.data}` · run store: `{request.root}`",
        "",
        f"Labelled {len(labelled)} sequence(s): "
        + (", ".join(labelled) or ("none" if reasons else "none (everything up to date)")),
        f"Stages: {', '.join(request.order(request.pipeline()))}",
        "",
    ]
    if reasons:
        lines += ["Not labelled this tick (tried again next tick):", ""]
        lines += [f"- `{seq}`: {why}" for seq, why in reasons.items()]
        lines.append("")
    if published["scored"]:
        h = published["headline"]
        lines.append(f"{brief_line(h)} · frames {h['frames']} ({h['mode']})")
        lines.append(f"Dashboard: `{published['dashboard']}`")
    else:
        lines.append("No scores: no ground truth or no score stage in this pipeline yet.")
    create_markdown_artifact("\n".join(lines), key=f"auto-label-{dataset_key(name)}", description=name)


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

    _quiet_prefect()
    dataset = name or request.dataset_name()
    request.order(request.pipeline())  # an unknown method or stage fails here, not at the first tick
    deployment = f"auto-label-{dataset_key(dataset)}"
    watch = ScheduleWatch(f"auto-label/{deployment}", say, every_s=check_every_s, grace_s=grace_s).start()
    try:
        _serve(request, cron, dataset, deployment)
    finally:
        watch.stop()


def _quiet_prefect() -> None:
    """One line per tick: Prefect's INFO lines (about ten a tick: submitting, opening the process,
    task states) off in this process and in the ticks' processes, unless PREFECT_LOGGING_LEVEL says
    otherwise (``PREFECT_LOGGING_LEVEL=INFO dsnet serve …`` shows them, as before)."""
    import logging
    import os

    if os.environ.get("PREFECT_LOGGING_LEVEL"):
        return
    os.environ["PREFECT_LOGGING_LEVEL"] = "WARNING"  # the tick subprocesses the runner starts
    for name, logger in list(logging.root.manager.loggerDict.items()):
        if (
            name.startswith("prefect")
            and isinstance(logger, logging.Logger)
            and logger.level < logging.WARNING
        ):
            logger.setLevel(logging.WARNING)


class _ShutdownNoise:
    """Drops asyncio's report of a task cancelled while Prefect's runner stops on SIGTERM (its
    control channel's reader, a traceback ending in ``CancelledError`` on every ``systemctl stop``);
    every other asyncio error is still logged."""

    def filter(self, record) -> bool:
        import asyncio

        exc = record.exc_info[1] if record.exc_info else None
        return not isinstance(exc, asyncio.CancelledError)


def _serve(request: LabelRequest, cron: str, dataset: str, deployment: str) -> None:
    import logging

    logging.getLogger("asyncio").addFilter(_ShutdownNoise())
    auto_label.serve(
        name=deployment,
        cron=cron,
        parameters={"request": request.model_dump(mode="json"), "dataset": dataset},
        description=f"Label new or stale sequences of {request.data} into {request.root}, score, refresh "
        "the dashboard.",
        print_starting_message=False,
    )
