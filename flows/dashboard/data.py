"""The tables one run contributes to the dashboard (parquet only, through pyarrow)."""

from __future__ import annotations

import posixpath
from dataclasses import dataclass
from typing import Any

import pyarrow as pa
import pyarrow.dataset as ds

from storage.contract import CONTRACTS, REPORT_TABLES
from storage.errors import StoreError
from storage.fs import RootFS
from storage.tables import read_table


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


def _rows(root: RootFS, name: str) -> list[dict[str, Any]]:
    spec = REPORT_TABLES[name]
    if not root.exists(posixpath.join("tables", name)):
        return []
    return read_table(root, spec).select(spec.schema.names).to_pylist()


def _frames(root: RootFS) -> dict[str, list[dict[str, Any]]]:
    spec = CONTRACTS["score"].table("frame_metrics")
    base = posixpath.join("tables", spec.name)
    if not root.exists(base):
        return {}
    part = ds.partitioning(pa.schema([("sequence", pa.string())]), flavor="hive")
    fs = None if root.local else root.fs
    table = ds.dataset(root.path(base), format="parquet", partitioning=part, filesystem=fs).to_table(
        columns=["sequence", "index", "frame_id", "pq", "miou", "n_points", "tp", "fp", "fn"]
    )
    out: dict[str, list[dict[str, Any]]] = {}
    for row in table.to_pylist():
        out.setdefault(row["sequence"], []).append(row)
    for rows in out.values():
        rows.sort(key=lambda r: r["index"])
    return dict(sorted(out.items()))


def load_run(uri: str, label: str, storage_options: dict | None = None) -> RunTables:
    """Read one run store's report tables. Raises StoreError when the run was never scored."""
    root = RootFS(uri, storage_options)
    runs = _rows(root, "score_run")
    if not runs:
        raise StoreError(root.url("tables/score_run"), "no score report here: run the score stage first")
    name = posixpath.basename(root.uri.rstrip("/")) or root.uri
    return RunTables(
        label=f"{label} · {name}",
        root=root.uri,
        run=runs[0],
        sequences=sorted(_rows(root, "score_sequences"), key=lambda r: r["sequence"]),
        classes=sorted(_rows(root, "score_classes"), key=lambda r: r["class_id"]),
        timings=_rows(root, "stage_timings"),
        bev=sorted(_rows(root, "score_bev"), key=lambda r: r["rank"]),
        review=sorted(_rows(root, "review_queue"), key=lambda r: r["rank"]),
        frames=_frames(root),
    )
