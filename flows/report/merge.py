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
from dsnet_core.metrics.nuscenes_scorer import NuScenesScorer
from dsnet_core.metrics.scoring import Scorer, restore_scorer
from dsnet_core.metrics.state import state_from_bytes
from flows.report.facts import config_hash, model_plan, timing_rows  # noqa: F401 (model_plan, timing_rows: re-exported)
from flows.report.label_report import LabelReport, write_label_report
from flows.report.pictures import bev_rows, legend_rows
from flows.report.refined import before_evaluators, refine_score_rows
from flows.report.tables import HEADLINE_KEYS, REPORT_TABLES, SCORING_KEYS
from storage.run import RunStore
from tasks.pipeline import Pipeline
from tasks.run_config import RunConfig, read_run
from tasks.score import FRAME_METRICS, ScoreConfig, block_state_name, make_evaluator

SCORE = "score"


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
    """
    m = store.read_manifest(sequence, SCORE)
    if m is None or m.status != "done" or m.n_items == 0:  # not scored, or no ground truth
        return None
    config = ScoreConfig.model_validate(m.config)
    ev = make_evaluator(config, label_map, model_map)
    for items in m.blocks:
        data = store.read_block_bytes(sequence, SCORE, block_state_name(items[0]))
        ev.merge(restore_scorer(make_evaluator(config, label_map, model_map), state_from_bytes(data)))
    return ev


def scoring_columns(ev: Scorer) -> dict[str, Any]:
    """The report's ``scoring`` columns of a scorer (tracking and expressible-class numbers are
    null for a benchmark without them)."""
    out: dict[str, Any] = dict.fromkeys(SCORING_KEYS)
    out["scoring"], out["class_mapping"] = ev.label_map.name, ""
    if isinstance(ev, NuScenesScorer):
        out["class_mapping"] = ev.mapping.file
        tr, sub, sub_tr = ev.tracking(), ev.result("expressible"), ev.tracking("expressible")
        values = {
            "pat": tr.pat,
            "tq": tr.tq,
            "ptq": tr.ptq,
            "sptq": tr.sptq,
            "pq_expressible": sub.panoptic.pq,
            "sq_expressible": sub.panoptic.sq,
            "rq_expressible": sub.panoptic.rq,
            "miou_expressible": sub.panoptic.miou,
            "lstq_expressible": sub_tr.lstq,
            "pat_expressible": sub_tr.pat,
        }
        out.update({k: float(v) if math.isfinite(v) else None for k, v in values.items()})
    return out


def _headline(res: EvalResult) -> dict[str, float | None]:
    p, t = res.panoptic, res.lstq
    out = {}
    for key in HEADLINE_KEYS:
        v = getattr(p, key) if hasattr(p, key) else getattr(t, key)
        out[key] = float(v) if math.isfinite(v) else None
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
                **_headline(res),
                **scoring_columns(ev),
                "tp": int(p.tp[ev.spec.include].sum()),
                "fp": int(p.fp[ev.spec.include].sum()),
                "fn": int(p.fn[ev.spec.include].sum()),
            }
        )
        total = ev if total is None else total.merge(ev)
    res = total.result()
    spec = total.spec
    hidden = set(total.mapping.unexpressible) if isinstance(total, NuScenesScorer) else set()
    to_gt = total.mapping.map_labels if isinstance(total, NuScenesScorer) else None
    class_rows = [
        {
            "class_id": int(k),
            "class": spec.names[k],
            "kind": "thing" if k in spec.things else "stuff",
            "expressible": int(k) not in hidden,
            **{
                key: float(getattr(res.panoptic.per_class[spec.names[k]], key))
                for key in ("pq", "sq", "rq", "iou")
            },
            **{key: int(getattr(res.panoptic.per_class[spec.names[k]], key)) for key in ("tp", "fp", "fn")},
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
        **_headline(res),
        **scoring_columns(total),
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
    return {s: store.read_table(s, FRAME_METRICS).to_pydict() for s in sequences if _scored(store, s)}


def read_report_table(store: RunStore, name: str):
    """A report table (pyarrow Table)."""
    return store.read_all(REPORT_TABLES[name])
