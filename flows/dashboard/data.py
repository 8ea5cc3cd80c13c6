"""The tables one run contributes to the dashboard (parquet only, through pyarrow)."""

from __future__ import annotations

import posixpath
from dataclasses import dataclass
from typing import Any

from flows.report.tables import REPORT_TABLES
from storage.errors import StoreError
from storage.run import RunStore
from tasks.score import frame_metrics_spec


@dataclass
class Labelled:
    """One run store's labelling report (:mod:`flows.report.label_tables`), as lists of row dicts.

    Attributes:
        run: the ``label_run`` row.
        sequences / classes / tracks / bev / transitions / refine_scores: rows of those tables.
        frames: ``label_frames`` rows by sequence, sorted by frame index.
        legend / legend_truth: ``class_legend`` rows of the model's map and of the ground truth's,
            by class id.
    """

    run: dict[str, Any]
    sequences: list[dict[str, Any]]
    classes: list[dict[str, Any]]
    frames: dict[str, list[dict[str, Any]]]
    tracks: list[dict[str, Any]]
    legend: dict[int, dict[str, Any]]
    legend_truth: dict[int, dict[str, Any]]
    bev: list[dict[str, Any]]
    transitions: list[dict[str, Any]]
    refine_scores: list[dict[str, Any]]

    @property
    def refined(self) -> bool:
        return any(s["refined"] for s in self.sequences)

    def name(self, class_id: int) -> str:
        row = self.legend.get(class_id)
        return row["class"] if row else str(class_id)


@dataclass
class RunTables:
    """One run store's report, as lists of row dicts.

    Attributes:
        label: short name shown on the page ("A", "B", … plus the root's last folder).
        root: the run store URI.
        run: the ``score_run`` row (None: nothing scored).
        sequences / classes / timings / bev / review: rows of the report tables.
        frames: ``frame_metrics`` rows by sequence, sorted by frame index.
        labelled: the labelling report (None: the run has none yet).
        progress: where an unfinished run is (:func:`run_progress`; None: every stage done).
    """

    label: str
    root: str
    run: dict[str, Any] | None
    sequences: list[dict[str, Any]]
    classes: list[dict[str, Any]]
    timings: list[dict[str, Any]]
    bev: list[dict[str, Any]]
    review: list[dict[str, Any]]
    frames: dict[str, list[dict[str, Any]]]
    labelled: Labelled | None = None
    progress: str | None = None

    @property
    def scored(self) -> bool:
        return self.run is not None


def _rows(store: RunStore, name: str) -> list[dict[str, Any]]:
    spec = REPORT_TABLES[name]
    if not store.has_table(spec):
        return []
    table = store.read_all(spec)
    # a report written before a metric was registered lacks its columns: shown as missing
    return table.select([n for n in spec.schema.names if n in table.column_names]).to_pylist()


def _by_sequence(rows: list[dict[str, Any]]) -> dict[str, list[dict[str, Any]]]:
    out: dict[str, list[dict[str, Any]]] = {}
    for row in rows:
        out.setdefault(row["sequence"], []).append(row)
    for rows_ in out.values():
        rows_.sort(key=lambda r: r["index"])
    return dict(sorted(out.items()))


def _frames(store: RunStore) -> dict[str, list[dict[str, Any]]]:
    if not store.has_table(frame_metrics_spec()):
        return {}
    table = store.read_all(frame_metrics_spec()).select(
        ["sequence", "index", "frame_id", "pq", "miou", "n_points", "tp", "fp", "fn"]
    )
    return _by_sequence(table.to_pylist())


def _labelled(store: RunStore) -> Labelled | None:
    runs = _rows(store, "label_run")
    if not runs:
        return None
    legend = _rows(store, "class_legend")
    return Labelled(
        run=runs[0],
        sequences=sorted(_rows(store, "label_sequences"), key=lambda r: r["sequence"]),
        classes=sorted(_rows(store, "label_classes"), key=lambda r: (r["sequence"], r["class_id"])),
        frames=_by_sequence(_rows(store, "label_frames")),
        tracks=_rows(store, "label_tracks"),
        legend={r["class_id"]: r for r in legend if r["map"] == "model"},
        legend_truth={r["class_id"]: r for r in legend if r["map"] == "truth"},
        bev=sorted(_rows(store, "label_bev"), key=lambda r: r["rank"]),
        transitions=_rows(store, "refine_transitions"),
        refine_scores=_rows(store, "refine_scores"),
    )


def run_progress(store: RunStore) -> str | None:
    """Where a run whose stages are not all done is: its first sequence and stage that is not done,
    ``sequence 00 is at stage infer (running, 2/5 blocks done)`` (``running``: a live run holds the
    stage's lock; ``stopped``: nobody does); None when every stage of every sequence is done (or
    only damaged: ``dsnet status`` says what; or the run's method is not one this install has)."""
    from storage.locks import is_stale
    from tasks.run_config import read_run
    from tasks.runner import stage_state

    run = read_run(store)
    try:
        pipeline = run.pipeline()
    except ValueError:  # a method this install does not know: its stages are not known here
        return None
    for seq in sorted(set(store.sequences()) | set(run.sequences)):
        for stage in pipeline.names():
            state, m, n_done = stage_state(store, pipeline, seq, stage, run)
            if state in ("done", "damaged"):
                continue
            if state == "partial":
                holder = store.root.read_json(store.lock_rel(seq, stage))
                live = bool(holder) and not is_stale(holder, run.options.stale_after_s)
                what = "failed" if m.status == "failed" else "running" if live else "stopped"
                what = f"{what}, {n_done}/{len(m.blocks)} blocks done"
            else:
                what = "not started" if state == "missing" else "stale: its input or settings changed"
            return f"sequence {seq} is at stage {stage} ({what})"
    return None


def load_run(uri: str, label: str, storage_options: dict | None = None) -> RunTables:
    """Read one run store's report tables.

    Raises:
        StoreError: not a run folder, or a run with no report yet.
    """
    store = RunStore(uri, storage_options)
    store.read_run_config()  # a file, or a folder that is no run store, is refused here
    runs = _rows(store, "score_run")
    labelled = _labelled(store)
    if not runs and labelled is None:
        raise StoreError(
            store.uri, "no report here yet: `dsnet label` writes it once a run's labels are done"
        )
    name = posixpath.basename(store.uri.rstrip("/")) or store.uri
    return RunTables(
        label=f"{label} · {name}",
        root=store.uri,
        run=runs[0] if runs else None,
        sequences=sorted(_rows(store, "score_sequences"), key=lambda r: r["sequence"]),
        classes=sorted(_rows(store, "score_classes"), key=lambda r: r["class_id"]),
        timings=_rows(store, "stage_timings"),
        bev=sorted(_rows(store, "score_bev"), key=lambda r: r["rank"]),
        review=sorted(_rows(store, "review_queue"), key=lambda r: r["rank"]),
        frames=_frames(store),
        labelled=labelled,
        progress=run_progress(store),
    )
