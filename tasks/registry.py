"""The stages, in pipeline order. A new stage adds one line here (and its contract)."""

from __future__ import annotations

from tasks.align import AlignStage
from tasks.base import Stage
from tasks.fuse import FuseStage
from tasks.infer import InferStage
from tasks.ingest import IngestStage
from tasks.score import ScoreStage
from tasks.shift import ShiftStage
from tasks.stitch import StitchStage

STAGES: dict[str, Stage] = {
    s.name: s
    for s in (
        IngestStage(),
        AlignStage(),
        InferStage(),
        ShiftStage(),
        FuseStage(),
        StitchStage(),
        ScoreStage(),
    )
}


def stage_order() -> list[str]:
    """Stage names, every stage after its upstream stages."""
    order: list[str] = []
    pending = dict(STAGES)
    while pending:
        ready = [n for n, s in pending.items() if all(u in order for u in s.upstream)]
        if not ready:
            raise ValueError(f"stage dependency cycle or unknown upstream among {sorted(pending)}")
        for name in ready:
            order.append(name)
            del pending[name]
    return order


def downstream_of(stage: str) -> list[str]:
    """Stages that read ``stage`` directly or indirectly, in order."""
    out: list[str] = []
    for name in stage_order():
        if any(u == stage or u in out for u in STAGES[name].upstream):
            out.append(name)
    return out
