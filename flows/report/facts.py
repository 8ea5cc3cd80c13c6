"""Facts of a run the reports share: its config hash, its model, its stage timings."""

from __future__ import annotations

import hashlib
import json
from typing import Any

from storage.run import RunStore
from tasks.base import CLASS_MAP
from tasks.pipeline import Pipeline
from tasks.run_config import RunConfig


def config_hash(run: RunConfig) -> str:
    """sha256[:16] of the run's stage configs (what decides the labels and the scores)."""
    payload = json.dumps(run.stages, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(payload.encode()).hexdigest()[:16]


def model_plan(store: RunStore, pipeline: Pipeline, sequences: list[str]) -> dict[str, Any]:
    """The plan of the first stage (the labels stage or one upstream of it) that recorded the
    model's class map: it holds ``model_card`` (``<checkpoint folder>@<weights sha256[:12]>``) and
    the class map. Empty when no model stage ran."""
    for seq in sequences:
        for stage in [*pipeline.upstream_closure(pipeline.labels), pipeline.labels]:
            m = store.read_manifest(seq, stage)
            if m is not None and CLASS_MAP in m.plan:
                return m.plan
    return {}


def timing_rows(store: RunStore, pipeline: Pipeline, sequences: list[str]) -> list[dict[str, Any]]:
    """One row per finished (sequence, stage) from its manifest's timings and counts."""
    rows = []
    for seq in sequences:
        for stage in pipeline.names():
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
