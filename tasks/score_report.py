"""The dataset-level score report: merge every scored sequence's accumulators, write report tables.

Reads the score stage's block states and ``frame_metrics`` table, the manifests, and (for the
pictures) the scans, stitch labels and ground truth of the worst frames; writes the tables of
:data:`storage.contract.REPORT_TABLES` under ``ROOT/tables/``. Every dataset-level number comes
from merged accumulators. Safe to call again at any time: it rewrites the tables whole.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from dsnet_core.metrics import EvalResult, PanopticEvaluator
from dsnet_core.metrics.state import restore_evaluator, state_from_bytes
from storage.contract import CONTRACTS, HEADLINE_KEYS, REPORT_TABLES
from storage.errors import StoreError
from storage.run import RunStore
from storage.tables import read_table, to_table, write_partition
from tasks.registry import stage_order
from tasks.score import PRED_ARRAY, PRED_STAGE, ScoreConfig, make_evaluator, state_rel

log = logging.getLogger(__name__)


@dataclass
class ScoreReport:
    """What :func:`write_report` computed (the same values as the tables it wrote)."""

    run: dict[str, Any]
    sequences: list[dict[str, Any]] = field(default_factory=list)
    classes: list[dict[str, Any]] = field(default_factory=list)
    tables: dict[str, str] = field(default_factory=dict)


def sequence_evaluator(store: RunStore, sequence: str) -> PanopticEvaluator | None:
    """The merged accumulators of one sequence's finished score stage (None if not scored)."""
    m = store.read_manifest(sequence, "score")
    if m is None or m.status != "done" or m.n_items == 0:  # not scored, or no ground truth
        return None
    config = ScoreConfig.model_validate(m.config)
    ev = make_evaluator(config)
    for items in m.blocks:
        data = store.root.read_bytes(state_rel(store, sequence, items[0]))
        if data is None:
            raise StoreError(store.root.url(state_rel(store, sequence, items[0])), "block state missing")
        ev.merge(restore_evaluator(ev.label_map, state_from_bytes(data)))
    return ev


def _headline(res: EvalResult) -> dict[str, float | None]:
    p, t = res.panoptic, res.lstq
    out = {}
    for key in HEADLINE_KEYS:
        v = getattr(p, key) if hasattr(p, key) else getattr(t, key)
        out[key] = float(v) if math.isfinite(v) else None
    return out


def config_hash(run: dict[str, Any]) -> str:
    """sha256[:16] of the run's stage configs (what decides the labels and the scores)."""
    payload = json.dumps(run.get("stages", {}), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(payload.encode()).hexdigest()[:16]


def model_card_id(store: RunStore, sequences: list[str]) -> str:
    """The model card id ``<checkpoint folder>@<weights sha256[:12]>`` of the run's infer stage
    (the checkpoint its manifest resolved: the configured one or a bundled model), from the card's
    JSON; "" when there is no model."""
    infer = next((m for seq in sequences if (m := store.read_manifest(seq, "infer")) is not None), None)
    folder = infer.plan.get("checkpoint") if infer is not None else None
    if not folder:
        return ""
    path = Path(folder)
    try:
        card = json.loads((path / "card.json").read_text())
    except (OSError, ValueError):
        return str(folder or "")
    return f"{path.name}@{str(card.get('weights_sha256', ''))[:12]}"


def write_report(store: RunStore, bev_frames: int = 6, review_rows: int = 30) -> ScoreReport | None:
    """Merge the scored sequences and write the report tables. Returns None when nothing is scored."""
    run = store.read_run_config()
    sequences = sorted(store.sequences())
    evals = {s: ev for s in sequences if (ev := sequence_evaluator(store, s)) is not None}
    if not evals:
        return None
    total: PanopticEvaluator | None = None
    seq_rows = []
    frames = _frame_table(store)
    for seq, ev in evals.items():
        res = ev.result()
        pts = frames.get(seq, {}).get("n_points", [])
        p = ev.panoptic
        seq_rows.append(
            {
                "sequence": seq,
                "frames": res.frames,
                "points": int(sum(pts)),
                **_headline(res),
                "tp": int(p.tp[ev.spec.include].sum()),
                "fp": int(p.fp[ev.spec.include].sum()),
                "fn": int(p.fn[ev.spec.include].sum()),
            }
        )
        total = ev if total is None else total.merge(ev)
    res = total.result()
    spec = total.spec
    class_rows = []
    for k in spec.include:
        c = res.panoptic.per_class[spec.names[k]]
        class_rows.append(
            {
                "class_id": int(k),
                "class": spec.names[k],
                "kind": "thing" if k in spec.things else "stuff",
                **{key: float(getattr(c, key)) for key in ("pq", "sq", "rq", "iou")},
                **{key: int(getattr(c, key)) for key in ("tp", "fp", "fn")},
            }
        )
    run_row = {
        "run_id": str(run.get("run_id", "")),
        "root": store.uri,
        "mode": str(res.mode),
        "model_card": model_card_id(store, sequences),
        "config_hash": config_hash(run),
        "min_points": total.min_points,
        "sequences": len(evals),
        "frames": res.frames,
        "points": int(sum(r["points"] for r in seq_rows)),
        **_headline(res),
        "created": time.time(),
    }
    out = ScoreReport(run_row, seq_rows, class_rows)
    out.tables["score_run"] = _write(store, "score_run", [run_row])
    out.tables["score_sequences"] = _write(store, "score_sequences", seq_rows)
    out.tables["score_classes"] = _write(store, "score_classes", class_rows)
    out.tables["stage_timings"] = _write(store, "stage_timings", timing_rows(store, sequences))
    out.tables["score_bev"] = _write(store, "score_bev", bev_rows(store, run, frames, total, bev_frames))
    out.tables["review_queue"] = _write(store, "review_queue", review_queue(store, sequences, review_rows))
    return out


def _write(store: RunStore, name: str, rows: list[dict[str, Any]]) -> str:
    spec = REPORT_TABLES[name]
    return write_partition(store.root, spec, {}, to_table(spec, rows))


def _frame_table(store: RunStore) -> dict[str, dict[str, list]]:
    """``frame_metrics`` by sequence (columns as lists), only sequences whose score stage is done."""
    out = {}
    for seq in store.sequences():
        m = store.read_manifest(seq, "score")
        if m is not None and m.status == "done":
            out[seq] = store.read_table(seq, "score", "frame_metrics").to_pydict()
    return out


def timing_rows(store: RunStore, sequences: list[str]) -> list[dict[str, Any]]:
    """One row per finished (sequence, stage) from its manifest's timings and counts."""
    rows = []
    for seq in sequences:
        for stage in stage_order():
            m = store.read_manifest(seq, stage)
            if m is None or m.status != "done":
                continue
            block_s = float(m.timings.get("block_s", 0.0))
            points = int(m.counts.get("points", 0))
            rows.append(
                {
                    "sequence": seq,
                    "stage": stage,
                    "items": m.n_items,
                    "points": points,
                    "wall_s": float(m.timings.get("wall_s", 0.0)),
                    "block_s": block_s,
                    "items_per_s": m.n_items / block_s if block_s > 0 else None,
                    "points_per_s": points / block_s if block_s > 0 else None,
                    "fingerprint": m.fingerprint,
                }
            )
    return rows


def worst_frames(frames: dict[str, dict[str, list]], n: int) -> list[tuple[str, int, str, float, int]]:
    """The ``n`` frames of lowest PQ (frames without a PQ are skipped): (seq, index, id, pq, points)."""
    cands = []
    for seq, t in frames.items():
        for i, fid, pq, npts in zip(t["index"], t["frame_id"], t["pq"], t["n_points"], strict=True):
            if pq is not None and math.isfinite(pq):
                cands.append((pq, seq, int(i), fid, int(npts)))
    cands.sort()
    return [(seq, i, fid, pq, npts) for pq, seq, i, fid, npts in cands[:n]]


def bev_rows(
    store: RunStore, run: dict, frames: dict[str, dict[str, list]], ev: PanopticEvaluator, n: int
) -> list[dict[str, Any]]:
    """Bird's-eye-view PNGs (prediction and ground truth) of the ``n`` worst frames."""
    from dsnet_core.io.formats import open_log
    from dsnet_core.viz.bev import label_colours, render_bev
    from dsnet_core.viz.png import encode_png

    if n <= 0:
        return []
    reader = open_log(run["data"], run.get("format", "auto"), run.get("reader_options"))
    lm = ev.label_map
    rows = []
    for rank, (seq, index, fid, pq, npts) in enumerate(worst_frames(frames, n)):
        ref = reader.frames(seq)[index]
        scan = reader.scan(ref)
        gt = reader.labels(ref)
        pred = store.arrays(seq, PRED_STAGE).read_item(index, [PRED_ARRAY])[PRED_ARRAY]
        extent = float(min(60.0, max(20.0, np.percentile(np.abs(scan[:, :2]), 95))))
        pics = {}
        for key, lab in (("png_pred", pred), ("png_gt", gt)):
            lab = np.asarray(lab, dtype=np.uint32)
            img = render_bev(scan[:, :2], label_colours(lab, lm), extent, 240, draw_last=(lab >> 16) > 0)
            pics[key] = encode_png(img)
        rows.append(
            {
                "rank": rank,
                "sequence": seq,
                "index": index,
                "frame_id": fid,
                "pq": pq,
                "n_points": npts,
                "extent_m": extent,
                **pics,
            }
        )
    return rows


_ID_COLS = ("instance", "id", "track_id", "instance_id")
_CLASS_COLS = ("class", "class_name", "class_id", "semantic", "cls")
_SIZE_COLS = ("points", "n_points", "size")
_ITEM_COLS = ("index", "first_frame")


def review_queue(store: RunStore, sequences: list[str], n: int) -> list[dict[str, Any]]:
    """The ``n`` least confident instances of every stage table that has a ``confidence`` column
    (the fuse instance table, the stitch track table), across sequences."""
    from dsnet_core.labels import load_label_map

    names = load_label_map("semantic-kitti").class_names
    cands = []
    for stage in stage_order():
        for spec in CONTRACTS[stage].tables:
            cols = spec.schema.names
            if "confidence" not in cols:
                continue
            id_col = next((c for c in _ID_COLS if c in cols), None)
            cls_col = next((c for c in _CLASS_COLS if c in cols), None)
            size_col = next((c for c in _SIZE_COLS if c in cols), None)
            item_col = next((c for c in _ITEM_COLS if c in cols), None)
            for seq in sequences:
                m = store.read_manifest(seq, stage)
                if m is None or m.status != "done":
                    continue
                t = store.read_table(seq, stage, spec.name).to_pydict()
                for r in range(len(t["confidence"])):
                    conf = t["confidence"][r]
                    if conf is None or not math.isfinite(conf):
                        continue
                    cls = None if cls_col is None else t[cls_col][r]
                    if cls_col == "class_id" and cls is not None and 0 <= cls < len(names):
                        cls = names[cls]
                    cands.append(
                        {
                            "source": f"{stage}/{spec.name}",
                            "sequence": seq,
                            "item": None if item_col is None else t[item_col][r],
                            "instance": int(t[id_col][r]) if id_col else r,
                            "class": "" if cls is None else str(cls),
                            "points": _total(t[size_col][r]) if size_col else None,
                            "confidence": float(conf),
                        }
                    )
    cands.sort(key=lambda r: (r["confidence"], r["source"], r["sequence"], r["instance"]))
    return [{"rank": i, **r} for i, r in enumerate(cands[:n])]


def _total(v) -> int | None:
    if v is None:
        return None
    if isinstance(v, list | tuple):
        return int(sum(x for x in v if x is not None))
    return int(v)


def read_report_table(store: RunStore, name: str):
    """A report table (pyarrow Table)."""
    return read_table(store.root, REPORT_TABLES[name])
