"""Offline refinement of a whole sequence's labels (pure numpy / numba / scipy).

Static-world voting in world voxels over a window of ±W frames, one class per track, tracks joined
across gaps in both directions, moving vs static tracks, an optional ground prior, and a per-frame
change record. :func:`plan_refinement` then :func:`refine_block` (any blocks, same result), or
:func:`refine_sequence` for a sequence in memory. See ``docs/refine.md``.
"""

from dsnet_core.refine.changes import FrameChange
from dsnet_core.refine.classes import ClassSets
from dsnet_core.refine.decisions import TrackDecisions, decide_tracks, track_rows
from dsnet_core.refine.frame import FrameInput, decode_labels, encode_labels
from dsnet_core.refine.ground import GroundSegmenter, Patchwork
from dsnet_core.refine.joining import Join
from dsnet_core.refine.params import GroundParams, RefineParams, TrackParams, VoteParams
from dsnet_core.refine.sequence import (
    RefinedFrame,
    RefinePlan,
    plan_refinement,
    refine_block,
    refine_sequence,
)

__all__ = [
    "ClassSets",
    "FrameChange",
    "FrameInput",
    "GroundParams",
    "GroundSegmenter",
    "Join",
    "Patchwork",
    "RefineParams",
    "RefinePlan",
    "RefinedFrame",
    "TrackDecisions",
    "TrackParams",
    "VoteParams",
    "decide_tracks",
    "decode_labels",
    "encode_labels",
    "plan_refinement",
    "refine_block",
    "refine_sequence",
    "track_rows",
]
