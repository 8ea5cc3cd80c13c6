"""After labelling: the report, the dashboard and the Prefect artifacts of a run store.

``publish(root, dataset)`` writes the report tables — the labelling report of every run, with or
without ground truth, and the score report (merged accumulators) where ground truth was scored —
and the dashboard (``ROOT/dashboard.html``). Inside a flow run, a scored run also gets two
artifacts with stable keys so the Prefect UI shows the latest per dataset:
``score-summary-<dataset>`` (markdown: every registered metric's value, the dashboard's location)
and ``score-classes-<dataset>`` (table: the registered per-class values). The labelling flow's own
progress and summary artifacts stay as they are.
"""

from __future__ import annotations

import logging
import re
import tempfile
from pathlib import Path
from typing import Any

from dsnet_core.metrics.registry import Column, columns
from flows.dashboard import build_dashboard
from flows.report import ScoreReport, write_report
from storage.run import DASHBOARD, RunStore
from tasks.pipeline import Pipeline

log = logging.getLogger(__name__)


def write_frame_confidence(store: RunStore, pipeline: Pipeline | None = None) -> int:
    """The ``frame_confidence`` report table of every labelled frame (scored or not); its row count."""
    from flows.report.confidence import frame_confidence_rows
    from flows.report.tables import REPORT_TABLES
    from tasks.run_config import read_run

    pipeline = pipeline or read_run(store).pipeline()
    rows = frame_confidence_rows(store, pipeline, store.sequences())
    store.write_run_table(REPORT_TABLES["frame_confidence"], rows)
    return len(rows)


def report_is_current(store: RunStore) -> bool:
    """Whether the store's report was made from the stages it holds now: the labelling report is
    there, every (sequence, stage) its ``stage_timings`` table recorded is still done with the same
    fingerprint, and no sequence has finished stages the report does not know."""
    from flows.report.tables import REPORT_TABLES

    timings, label_run = REPORT_TABLES["stage_timings"], REPORT_TABLES["label_run"]
    if not (store.has_table(timings) and store.has_table(label_run)):
        return False
    rows = store.read_all(timings).select(["sequence", "stage", "fingerprint"]).to_pylist()
    for r in rows:
        m = store.read_manifest(r["sequence"], r["stage"])
        if m is None or m.status != "done" or m.fingerprint != r["fingerprint"]:
            return False
    return {r["sequence"] for r in rows} >= set(store.sequences())


def refresh_report(root: str, storage_options: dict | None = None) -> bool:
    """Write the report of run ``root`` unless it is current (:func:`report_is_current`); whether it
    was written.

    Raises:
        StoreError: ``root`` is no run folder.
        DataFormatError: the report had to be written and the run's log no longer opens.
    """
    from tasks.run_config import read_run

    store = RunStore(root, storage_options)
    run = read_run(store)  # a file, or a folder that is no run store, is refused here
    if report_is_current(store):
        return False
    write_report(store, run.pipeline())
    return True


def dataset_key(name: str) -> str:
    """An artifact key part: lowercase letters, digits, dashes (``KITTI_odo/v2`` -> ``kitti-odo-v2``)."""
    key = re.sub(r"[^a-z0-9]+", "-", str(name).lower()).strip("-")
    return key or "dataset"


def write_dashboard(store: RunStore, others: list[str] | None = None) -> str:
    """Build the dashboard of this run (plus ``others`` side by side) into ``ROOT/dashboard.html``."""
    opts = store.storage_options or None
    with tempfile.TemporaryDirectory() as tmp:
        page = build_dashboard([store.uri, *(others or [])], Path(tmp) / DASHBOARD, storage_options=opts)
        return store.write_dashboard(page.read_bytes())


def _value(c: Column, v) -> str:
    if v is None:
        return "–"
    return str(int(v)) if c.kind == "count" else f"{100 * v:.1f}"


def brief_line(values: dict[str, Any], bold: bool = False) -> str:
    """The brief numbers (``Column.brief`` of the registered metrics) of ``values`` as one line:
    ``PQ 51.2 · mIoU 55.0 · LSTQ 60.1 · mIoU (present) 61.3 · PQ (present) 57.0`` (``bold``: each
    number in markdown bold)."""
    mark = "**" if bold else ""
    return " · ".join(
        f"{mark}{c.label} {_value(c, values.get(c.key))}{mark}"
        for c in columns("run")
        if c.brief and c.key in values
    )


def summary_markdown(report: ScoreReport, dataset: str, dashboard: str) -> str:
    """The markdown summary: the brief numbers, every registered metric value the run has, scoring
    mode, model, the dashboard's location."""
    r = report.run
    rows = [c for c in columns("run") if r.get(c.key) is not None]
    lines = [
        f"# Scores · {dataset}",
        "",
        brief_line(r, bold=True),
        "",
        "| metric | value |",
        "|---|---|",
        *(f"| {c.label} | {_value(c, r[c.key])} |" for c in rows),
        "",
        "(present): mean over the classes with ground-truth points; the official means count absent "
        "classes as 0.",
        "",
        f"{r['sequences']} sequences, {r['frames']} frames, {r['points']} points · scoring mode "
        f"`{r['mode']}` · model `{r['model_card'] or '-'}` · config `{r['config_hash']}` · "
        f"run `{r['run_id']}`",
        "",
        f"Dashboard: `{dashboard}`",
        "",
        f"Run store: `{r['root']}`",
    ]
    return "\n".join(lines)


def class_table(report: ScoreReport) -> list[dict[str, Any]]:
    """Per-class rows for the table artifact: every registered per-class column (fractions under
    their label in percent with one decimal: ``PQ``, ``IoU``; counts under their key: ``tp``)."""
    cols = columns("class")

    def show(k: Column, v):
        return v if v is None or k.kind == "count" else round(100 * v, 1)

    return [
        {
            "class": c["class"],
            "kind": c["kind"],
            **{k.key if k.kind == "count" else k.label: show(k, c.get(k.key)) for k in cols},
        }
        for c in report.classes
    ]


def publish(
    root: str,
    dataset: str,
    artifacts: bool = True,
    storage_options: dict | None = None,
    pipeline: Pipeline | None = None,
) -> dict:
    """Report tables, dashboard and (in a flow run) artifacts for one run store.

    ``pipeline`` is the run's method (default: the one its run config records).

    Returns:
        ``{"scored": bool, "dashboard": location, "headline": {...}}`` (headline: empty when
        nothing was scored).
    """
    store = RunStore(root, storage_options)
    report = write_report(store, pipeline)
    dashboard = write_dashboard(store)
    if report is None:
        log.info("nothing scored in %s (no ground truth, or no score stage yet)", store.uri)
        return {"scored": False, "dashboard": dashboard, "headline": {}}
    if artifacts:
        from prefect.artifacts import create_markdown_artifact, create_table_artifact

        key = dataset_key(dataset)
        create_markdown_artifact(
            summary_markdown(report, dataset, dashboard), key=f"score-summary-{key}", description=dataset
        )
        create_table_artifact(class_table(report), key=f"score-classes-{key}", description=dataset)
    brief = [c.key for c in columns("run") if c.brief]
    headline = {k: report.run.get(k) for k in (*brief, "mode", "frames")}
    return {"scored": True, "dashboard": dashboard, "headline": headline}
