"""Benchmark-exact scoring: PQ family, mIoU, LSTQ (4D-PLS) and the Panoptic nuScenes metrics.

numpy only. Every metric is computed from a frame's *cells* (distinct (gt label, pred label)
pairs and their point counts, one sort per frame) by streaming accumulators with ``add``,
``merge`` and an idempotent ``result``. Modes (:class:`Mode`): ``official`` reproduces the
public evaluators to 1e-12, quirks included; ``corrected`` fixes the defects docs/metrics.md lists.

Entry points:
    PanopticEvaluator               SemanticKITTI raw ``.label`` arrays (or train ids via
                                    ``add_train``) -> EvalResult (PQ family + mIoU + LSTQ),
                                    ``result_by_sequence()`` and per-frame FrameRow records;
                                    ``class_rows``/``summary_row`` flatten results into table rows.
    NuScenesPanopticEvaluator       Panoptic nuScenes PQ family (``read_panoptic_npz``).
    PanopticTrackingAccumulator     Panoptic nuScenes LSTQ/PTQ/sPTQ/TQ/PAT over ``NuScenesCells``.
    pair_label_files                GT/prediction folders paired by file name (``dsnet eval``).
    registry.METRICS / register     the metrics every scorer computes (``registry.py``): add one
                                    as a module with one ``register`` call.
    present_class_means             means over the classes with ground truth (``present.py``).
"""

from .evaluator import PanopticEvaluator
from .lstq import LSTQAccumulator
from .nuscenes import NuScenesCells, NuScenesPanopticEvaluator, read_panoptic_npz, write_panoptic_npz
from .nuscenes_track import PanopticTrackingAccumulator, TrackingResult
from .pairing import LabelPair, pair_label_files
from .panoptic import PanopticAccumulator, ReferenceOverflowError
from .present import present_class_means
from .report import ClassScore, EvalResult, FrameRow, LSTQResult, Mode, PQResult, class_rows, summary_row

__all__ = [
    "ClassScore",
    "EvalResult",
    "FrameRow",
    "LSTQAccumulator",
    "LSTQResult",
    "LabelPair",
    "Mode",
    "NuScenesCells",
    "NuScenesPanopticEvaluator",
    "PQResult",
    "PanopticAccumulator",
    "PanopticEvaluator",
    "PanopticTrackingAccumulator",
    "ReferenceOverflowError",
    "TrackingResult",
    "class_rows",
    "pair_label_files",
    "present_class_means",
    "read_panoptic_npz",
    "summary_row",
    "write_panoptic_npz",
]
