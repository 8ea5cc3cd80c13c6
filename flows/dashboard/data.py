"""The tables one run contributes to the dashboard (parquet only, through pyarrow)."""

from __future__ import annotations

import posixpath
from dataclasses import dataclass
from typing import Any

from flows.report.tables import REPORT_TABLES
from storage.errors import StoreError
from storage.run import RunStore
from tasks.score import FRAME_METRICS


@dataclass
class RunTables:
    """One run store's score report, as lists of row dicts.

    Attributes:
        label: short name shown on the page ("A", "B", … plus the root's last folder).
        root: the run store URI.
        run: the ``score_run`` row.
        sequences / classes / timings / bev / review: rows of the report tables.
        frames: ``frame_metrics`` rows by sequence, sorted by frame index.
    """

    label: str
    root: str
    run: dict[str, Any]
    sequences: list[dict[str, Any]]
    classes: list[dict[str, Any]]
    timings: list[dict[str, Any]]
    bev: list[dict[str, Any]]
    review: list[dict[str, Any]]
    frames: dict[str, list[dict[str, Any]]]


def _rows(store: RunStore, name: str) -> list[dict[str, Any]]:
    spec = REPORT_TABLES[name]
    if not store.has_table(spec):
        return []
    return store.read_all(spec).select(spec.schema.names).to_pylist()


def _frames(store: RunStore) -> dict[str, list[dict[str, Any]]]:
    if not store.has_table(FRAME_METRICS):
        return {}
    table = store.read_all(FRAME_METRICS).select(
        ["sequence", "index", "frame_id", "pq", "miou", "n_points", "tp", "fp", "fn"]
    )
    out: dict[str, list[dict[str, Any]]] = {}
    for row in table.to_pylist():
        out.setdefault(row["sequence"], []).append(row)
    for rows in out.values():
        rows.sort(key=lambda r: r["index"])
    return dict(sorted(out.items()))


def load_run(uri: str, label: str, storage_options: dict | None = None) -> RunTables:
    """Read one run store's report tables. Raises StoreError when the run was never scored."""
    store = RunStore(uri, storage_options)
    runs = _rows(store, "score_run")
    if not runs:
        where = store.table_url(REPORT_TABLES["score_run"])
        raise StoreError(where, "no score report here: run the score stage first")
    name = posixpath.basename(store.uri.rstrip("/")) or store.uri
    return RunTables(
        label=f"{label} · {name}",
        root=store.uri,
        run=runs[0],
        sequences=sorted(_rows(store, "score_sequences"), key=lambda r: r["sequence"]),
        classes=sorted(_rows(store, "score_classes"), key=lambda r: r["class_id"]),
        timings=_rows(store, "stage_timings"),
        bev=sorted(_rows(store, "score_bev"), key=lambda r: r["rank"]),
        review=sorted(_rows(store, "review_queue"), key=lambda r: r["rank"]),
        frames=_frames(store),
    )
