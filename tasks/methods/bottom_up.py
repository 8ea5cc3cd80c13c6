"""The pipeline shape DS-Net and D-PLS share: ingest → align → the method's model stages →
clustering (``shift``) and fusion (``fuse``) of the model's per-point outputs → temporal
association → score."""

from __future__ import annotations

from tasks.align import AlignStage
from tasks.fuse import FuseStage
from tasks.ingest import IngestStage
from tasks.pipeline import Pipeline
from tasks.score import ScoreStage
from tasks.shift import ShiftStage
from tasks.stitch import StitchStage
from tasks.track import TrackStage

TEMPORAL = {"stitch": StitchStage, "track": TrackStage}
"""How instance ids become sequence-wide: stitching overlapping volumes, or tracking instances."""


def bottom_up(name: str, model: tuple, source: str, temporal: str) -> Pipeline:
    """The shared shape; ``source`` is the model stage whose per-point outputs are clustered."""
    stages = (
        IngestStage(),
        AlignStage(),
        *model,
        ShiftStage(source=source),
        FuseStage(source=source),
        TEMPORAL[temporal](),
        ScoreStage(labels=temporal),
    )
    return Pipeline(name, stages, labels=temporal, options=(("temporal", temporal),))
