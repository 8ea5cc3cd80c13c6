"""The methods a run can use, each a factory of its :class:`~tasks.pipeline.Pipeline`.

``dsnet`` is DS-Net (k = 1) and 4D-DS-Net (k > 1): ingest → align → infer → shift → fuse →
stitch (or track) → score. ``most`` is MOST: ingest → align (single scans) → most → track → score.
``dpls`` is D-PLS: ingest → align → prior → dpls → shift → fuse → stitch (or track) → score.
A new method adds one factory to :data:`METHODS`; stages shared with another
method (ingest, align) keep their names, so switching methods recomputes only what differs.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from tasks.align import AlignStage
from tasks.dpls import DplsStage
from tasks.fuse import FuseStage
from tasks.infer import InferStage
from tasks.ingest import IngestStage
from tasks.most import MostStage
from tasks.pipeline import Pipeline
from tasks.prior import PriorStage
from tasks.score import ScoreStage
from tasks.shift import ShiftStage
from tasks.stitch import StitchStage
from tasks.track import TrackStage

TEMPORAL = {"stitch": StitchStage, "track": TrackStage}
"""How instance ids become sequence-wide: stitching overlapping volumes, or tracking instances."""


def _bottom_up(name: str, model: tuple, source: str, temporal: str) -> Pipeline:
    """Ingest → align → ``model`` stages → clustering and fusion of ``source``'s per-point outputs →
    ``temporal`` association → score: the shape DS-Net and D-PLS share.

    Raises:
        ValueError: an unknown ``temporal``.
    """
    if temporal not in TEMPORAL:
        raise ValueError(f"unknown temporal association {temporal!r}; choose one of {sorted(TEMPORAL)}")
    stages = (
        IngestStage(),
        AlignStage(),
        *model,
        ShiftStage(source=source),
        FuseStage(source=source),
        TEMPORAL[temporal](),
        ScoreStage(labels=temporal),
    )
    options = () if temporal == "stitch" else (("temporal", temporal),)
    return Pipeline(name, stages, labels=temporal, options=options)


def dsnet(temporal: str = "stitch") -> Pipeline:
    """DS-Net / 4D-DS-Net: offsets → dynamic shifting → fusion → ``temporal``: stitching across
    volumes (4D-DS-Net, k > 1) or tracking each frame's instances (k = 1 + tracking).

    Raises:
        ValueError: an unknown ``temporal``.
    """
    return _bottom_up("dsnet", (InferStage(),), "infer", temporal)


def most(temporal: str = "track") -> Pipeline:
    """MOST: detections, memberships and learned velocities per frame, tracked into sequence ids.

    Raises:
        ValueError: a ``temporal`` other than ``track`` (MOST's frames share no volume to stitch).
    """
    if temporal != "track":
        raise ValueError(
            f"method most associates over time by tracking only (--temporal track), not {temporal!r}"
        )
    stages = (IngestStage(), AlignStage(), MostStage(), TrackStage(source="most"), ScoreStage(labels="track"))
    return Pipeline("most", stages, labels="track")


def dpls(temporal: str = "stitch") -> Pipeline:
    """D-PLS: single-scan semantic priors (the user's files or the bundled model's) aggregated into
    the volumes, the prior-conditioned instance network, clustering (DBSCAN by default, set in
    ``shift``'s config), majority vote over the prior's classes, then ``temporal`` as for DS-Net.

    Raises:
        ValueError: an unknown ``temporal``.
    """
    return _bottom_up("dpls", (PriorStage(), DplsStage()), "dpls", temporal)


METHODS: dict[str, Callable[..., Pipeline]] = {"dsnet": dsnet, "most": most, "dpls": dpls}
DEFAULT_METHOD = "dsnet"


def get_pipeline(method: str = DEFAULT_METHOD, **options: Any) -> Pipeline:
    """The pipeline of a method, built with its options.

    Raises:
        ValueError: unknown method (the message lists the methods).
    """
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; methods are {sorted(METHODS)}")
    return METHODS[method](**options)


def run_pipeline(run: dict[str, Any]) -> Pipeline:
    """The pipeline a run config records (``method`` and ``method_options``; ``dsnet`` for run stores
    written before methods existed)."""
    return get_pipeline(run.get("method", DEFAULT_METHOD), **run.get("method_options", {}))
