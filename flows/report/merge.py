"""The run report: the labelling report of every run (:mod:`flows.report.label_report`), then the
dataset-level score report where ground truth was scored.

The score report reads the score stage's block states and ``frame_metrics`` table, the manifests,
and (for the pictures) the scans, final labels and ground truth of the worst frames; where refine
made the final labels, it scores the labels refine read too (:mod:`flows.report.refined`). It
writes the tables of :data:`flows.report.tables.REPORT_TABLES` under ``ROOT/tables/``. Every
dataset-level number comes from merged accumulators. Safe to call again at any time: it rewrites
the tables whole.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

from dsnet_core.labels import LabelMap
from dsnet_core.metrics import EvalResult
from dsnet_core.metrics.registry import columns
from dsnet_core.metrics.scoring import Scorer, restore_scorer
from dsnet_core.metrics.state import state_from_bytes
from flows.report.facts import config_hash, model_plan, timing_rows  # noqa: F401 (model_plan, timing_rows: re-exported)
from flows.report.label_report import LabelReport, write_label_report
from flows.report.pictures import bev_rows, legend_rows
from flows.report.refined import before_evaluators, refine_score_rows
from flows.report.tables import REPORT_TABLES
from storage.errors import StoreError
from storage.run import RunStore
from tasks.pipeline import Pipeline
from tasks.run_config import RunConfig, read_run
from tasks.score import ScoreConfig, ScoreStage, block_state_name, frame_metrics_spec, make_evaluator

SCORE = ScoreStage.name


@dataclass
class ScoreReport:
    """What :func:`write_report` computed (the same values as the tables it wrote)."""

    run: dict[str, Any]
    sequences: list[dict[str, Any]] = field(default_factory=list)
    classes: list[dict[str, Any]] = field(default_factory=list)
    tables: dict[str, str] = field(default_factory=dict)
    truth_map: LabelMap | None = None  # the ground truth's label map (the scored pictures' colours)


def sequence_evaluator(store: RunStore, sequence: str, label_map, model_map=None) -> Scorer | None:
    """The merged accumulators of one sequence's finished score stage (None if not scored), its
    blocks merged in order.

    Args:
        label_map: the ground truth's label map.
        model_map: the model's (default: the same; another goes through their class mapping).

    Raises:
        StoreError: a block state this version does not read (an older layout, or another set of
            metrics), naming the file.
    """
    m = store.read_manifest(sequence, SCORE)
    if m is None or m.status != "done" or m.n_items == 0:  # not scored, or no ground truth
        return None
    config = ScoreConfig.model_validate(m.config)
    ev = make_evaluator(config, label_map, model_map)
    for items in m.blocks:
        name = block_state_name(items[0])
        data = store.read_block_bytes(sequence, SCORE, name)
        try:
            part = restore_scorer(make_evaluator(config, label_map, model_map), state_from_bytes(data))
        except ValueError as exc:  # a state of another layout or set of metrics: never misread
            raise StoreError(store.root.url(store.block_bytes_rel(sequence, SCORE, name)), str(exc)) from None
        ev.merge(part)
    return ev


def scoring_columns(ev: Scorer) -> dict[str, Any]:
    """How a scorer scored: the metric family (the ground truth's map) and the class mapping file."""
    return {"scoring": ev.label_map.name, "class_mapping": ev.mapping.file if ev.mapping is not None else ""}


def metric_row(res: EvalResult, level: str = "run") -> dict[str, Any]:
    """The registered metrics' columns of ``level`` from a result: finite values as they are, NaN,
    inf and metrics the scorer lacks as null (counts as int)."""
    values = res.values
    out: dict[str, Any] = {}
    for c in columns(level):
        v = values.get(c.key)
        if v is None or not math.isfinite(v):
            out[c.key] = None
        else:
            out[c.key] = int(v) if c.kind == "count" else float(v)
    return out


def class_metric_row(row: dict[str, float]) -> dict[str, Any]:
    """One class's registered per-class columns (null where a metric has none for it)."""
    out: dict[str, Any] = {}
    for c in columns("class"):
        v = row.get(c.key)
        out[c.key] = None if v is None else int(v) if c.kind == "count" else float(v)
    return out


SCORE_TABLES = ("score_run", "score_sequences", "score_classes", "score_bev", "refine_scores")
"""The tables only a scored run has (removed when a run no longer scores anything)."""


def write_report(
    store: RunStore, pipeline: Pipeline | None = None, bev_frames: int = 6, review_rows: int = 30
) -> ScoreReport | None:
    """Write the labelling report of every run (:func:`~flows.report.label_report.write_label_report`)
    and, where ground truth was scored, the score report. Returns the score report (None when
    nothing is scored; score tables of an earlier scored run are then removed).

    Args:
        pipeline: the run's method (default: the one its run config records).
        bev_frames: pictures of this many worst (scored) and least confident frames.
        review_rows: instances in the review queue.
    """
    run = read_run(store)
    pipeline = pipeline or run.pipeline()
    labelled = write_label_report(store, pipeline, run, bev_frames, review_rows)
    scored = _score_report(store, pipeline, run, labelled, bev_frames)
    legend = legend_rows(labelled.label_map) if labelled.label_map is not None else []
    if scored is not None:
        legend += legend_rows(scored.truth_map, "truth")
    else:
        for name in SCORE_TABLES:
            store.remove_run_table(REPORT_TABLES[name])
    store.write_run_table(REPORT_TABLES["class_legend"], legend)
    return scored


def _score_report(
    store: RunStore, pipeline: Pipeline, run: RunConfig, labelled: LabelReport, bev_frames: int
) -> ScoreReport | None:
    """Merge the scored sequences and write the score report tables (None when nothing is scored)."""
    sequences = sorted(store.sequences())
    if SCORE not in pipeline or not any(_scored(store, s) for s in sequences):
        return None
    gt_map = run.open_log().label_map
    model, model_map = labelled.model, labelled.label_map
    evals = {s: ev for s in sequences if (ev := sequence_evaluator(store, s, gt_map, model_map)) is not None}
    if not evals:
        return None
    before = before_evaluators(store, pipeline, run, list(evals), gt_map, model_map)
    total: Scorer | None = None
    seq_rows = []
    frames = _frame_table(store, sequences)
    for seq, ev in evals.items():
        res = ev.result()
        p = ev.panoptic
        seq_rows.append(
            {
                "sequence": seq,
                "frames": res.frames,
                "points": int(sum(frames.get(seq, {}).get("n_points", []))),
                **scoring_columns(ev),
                **metric_row(res),
                "tp": int(p.tp[ev.spec.include].sum()),
                "fp": int(p.fp[ev.spec.include].sum()),
                "fn": int(p.fn[ev.spec.include].sum()),
            }
        )
        total = ev if total is None else total.merge(ev)
    res = total.result()
    spec = total.spec
    hidden, to_gt = total.unexpressible, total.to_truth
    class_rows = [
        {
            "class_id": int(k),
            "class": spec.names[k],
            "kind": "thing" if k in spec.things else "stuff",
            "expressible": int(k) not in hidden,
            **class_metric_row(res.classes.get(spec.names[k], {})),
        }
        for k in spec.include
    ]
    run_row = {
        "run_id": run.run_id or "",
        "root": store.uri,
        "mode": str(res.mode),
        "model_card": str(model.get("model_card", "")),
        "config_hash": config_hash(run),
        "min_points": total.min_points,
        "sequences": len(evals),
        "frames": res.frames,
        "points": int(sum(r["points"] for r in seq_rows)),
        **scoring_columns(total),
        **metric_row(res),
        "created": time.time(),
    }
    out = ScoreReport(run_row, seq_rows, class_rows, truth_map=total.label_map)
    for name, rows in (
        ("score_run", [run_row]),
        ("score_sequences", seq_rows),
        ("score_classes", class_rows),
        ("score_bev", bev_rows(store, pipeline, run, frames, total.label_map, bev_frames, to_gt)),
        ("refine_scores", refine_score_rows(before, seq_rows, class_rows, run_row)),
    ):
        out.tables[name] = store.write_run_table(REPORT_TABLES[name], rows)
    return out


def _scored(store: RunStore, sequence: str) -> bool:
    m = store.read_manifest(sequence, SCORE)
    return m is not None and m.status == "done"


def _frame_table(store: RunStore, sequences: list[str]) -> dict[str, dict[str, list]]:
    """``frame_metrics`` by sequence (columns as lists), only sequences whose score stage is done."""
    return {s: store.read_table(s, frame_metrics_spec()).to_pydict() for s in sequences if _scored(store, s)}


def read_report_table(store: RunStore, name: str):
    """A report table (pyarrow Table)."""
    return store.read_all(REPORT_TABLES[name])
