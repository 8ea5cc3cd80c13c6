"""Scoring modes and result records (plain dataclasses; ``to_dict`` gives JSON-ready values)."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from enum import StrEnum


class Mode(StrEnum):
    """How faithfully to follow the public evaluators.

    ``official`` reproduces the benchmark code to 1e-12, defects included (see docs/metrics.md);
    ``corrected`` fixes the documented defects. Every result records its mode.
    """

    OFFICIAL = "official"
    CORRECTED = "corrected"


def as_mode(mode: Mode | str) -> Mode:
    """Parse a mode name; raise ``ValueError`` naming the valid ones."""
    try:
        return Mode(str(mode).lower())
    except ValueError:
        raise ValueError(f"unknown scoring mode {mode!r}: use 'official' or 'corrected'") from None


@dataclass(frozen=True)
class ClassScore:
    """Scores of one train class (in [0, 1]) and its segment counts."""

    pq: float
    sq: float
    rq: float
    iou: float
    tp: int
    fp: int
    fn: int
    thing: bool = False


@dataclass(frozen=True)
class PQResult:
    """The PQ family and mIoU of a set of frames (SemanticKITTI ``evaluate_panoptic.py`` semantics).

    Means run over the evaluated classes (absent classes count 0); ``per_class`` maps class name
    to :class:`ClassScore` for every evaluated class.
    """

    mode: Mode
    pq: float
    sq: float
    rq: float
    pq_dagger: float
    pq_things: float
    sq_things: float
    rq_things: float
    pq_stuff: float
    sq_stuff: float
    rq_stuff: float
    miou: float
    per_class: dict[str, ClassScore] = field(default_factory=dict)


@dataclass(frozen=True)
class LSTQResult:
    """LSTQ and its parts (4D-PLS ``Panoptic4DEval`` semantics, or the Panoptic nuScenes variant).

    ``s_assoc`` is NaN when no ground-truth thing tube exists (the reference divides by zero).
    """

    mode: Mode
    lstq: float
    s_assoc: float
    s_cls: float
    iou_things: float
    iou_stuff: float
    n_tubes: int
    per_class_iou: dict[str, float] = field(default_factory=dict)


@dataclass(frozen=True)
class FrameRow:
    """Per-frame scores, one row per scored frame (for a parquet table later).

    ``pq`` averages the classes seen in this frame (tp + fp + fn > 0), ``miou`` the classes with a
    non-zero union in this frame; both are NaN when the frame has none.
    """

    sequence: str
    frame: str
    n_points: int
    n_valid: int
    pq: float
    sq: float
    rq: float
    miou: float
    tp: int
    fp: int
    fn: int
    values: dict[str, float] = field(default_factory=dict)

    def to_dict(self) -> dict[str, object]:
        """The fields, every registered metric's per-frame value (``values``) as a field too."""
        out = asdict(self)
        values = out.pop("values")
        return {**out, **values}


@dataclass(frozen=True)
class EvalResult:
    """Everything ``dsnet eval`` reports: PQ family, mIoU, LSTQ family, frames scored, mode.

    ``values`` holds every registered metric's run-level values (:mod:`.registry`, official ones
    included) and ``classes`` their per-class values; both are empty for the per-sequence results
    of :meth:`~.evaluator.PanopticEvaluator.result_by_sequence`, which hold the PQ family and LSTQ.
    """

    mode: Mode
    frames: int
    panoptic: PQResult
    lstq: LSTQResult
    values: dict[str, float] = field(default_factory=dict)
    classes: dict[str, dict[str, float]] = field(default_factory=dict)

    def scores(self) -> dict[str, float]:
        """The run-level values by key: ``values``, or the PQ family's and LSTQ's fields without."""
        if self.values:
            return dict(self.values)
        p, t = asdict(self.panoptic), asdict(self.lstq)
        out = {k: v for k, v in p.items() if isinstance(v, float)}
        out.update({k: v for k, v in t.items() if isinstance(v, float)})
        return out

    def to_dict(self) -> dict[str, object]:
        """The JSON object of ``dsnet eval --json`` (a published interface; NaN/inf become null):
        ``mode``, every run-level value by key, ``per_class`` (each class's fractions: PQ, SQ, RQ,
        IoU and any other metric's), ``frames``."""
        out: dict[str, object] = {"mode": str(self.mode)}
        out.update({k: _json_float(v) for k, v in self.scores().items()})
        classes = self.classes or {n: asdict(c) for n, c in self.panoptic.per_class.items()}
        out["per_class"] = {
            name: {k: _json_float(v) for k, v in row.items() if isinstance(v, float)}
            for name, row in classes.items()
        }
        out["frames"] = self.frames
        return out


def class_rows(result: EvalResult, **extra: object) -> list[dict[str, object]]:
    """One row per class (``class, thing, pq, sq, rq, iou, tp, fp, fn, mode`` + ``extra``)."""
    return [
        {"class": name, **asdict(c), "mode": str(result.mode), **extra}
        for name, c in result.panoptic.per_class.items()
    ]


def summary_row(result: EvalResult, **extra: object) -> dict[str, object]:
    """The run-level (or sequence-level) scores as one flat row: ``to_dict`` without ``per_class``."""
    row = {k: v for k, v in result.to_dict().items() if k != "per_class"}
    return {**row, **extra}


def _json_float(x: float) -> float | None:
    """NaN/inf are not JSON: report them as null."""
    return None if not math.isfinite(x) else float(x)
