"""Panoptic nuScenes: label decoding, ``{token}_panoptic.npz`` files and the PQ-family scorer.

Ground truth is ``general class * 1000 + instance`` (uint16) mapped to the 16 challenge classes
through the label map; predictions are ``challenge class * 1000 + instance``. Segments are keyed
by the whole panoptic label, min_points is 15, classes 1..10 are things and 11..16 stuff.
The tracking metrics (LSTQ variant, PTQ, sPTQ, PAT) are in :mod:`.nuscenes_track`.
"""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np

from dsnet_core.errors import LabelFormatError
from dsnet_core.labels import LabelMap, load_label_map

from .cells import Cells, check_labels
from .decode import ClassSpec, make_cells
from .panoptic import PanopticAccumulator
from .report import Mode, PQResult, as_mode

NUSCENES_MIN_POINTS = 15


class NuScenesGtDecoder:
    """Ground truth: class = ``learning_map[label // 1000]``, id = the whole label."""

    def __init__(self, label_map: LabelMap) -> None:
        self.lut = label_map.lut(66, fill=0).astype(np.int64)  # uint16 // 1000 ≤ 65

    def classes(self, labels: np.ndarray) -> np.ndarray:
        return self.lut[(labels // np.uint64(1000)).astype(np.int64)]

    def ids(self, labels: np.ndarray) -> np.ndarray:
        return labels.astype(np.int64)


class NuScenesPredDecoder:
    """Predictions: class = ``label // 1000`` (a challenge class), id = the whole label."""

    def __init__(self, n_classes: int) -> None:
        self.n_classes = n_classes

    def classes(self, labels: np.ndarray) -> np.ndarray:
        cls = (labels // np.uint64(1000)).astype(np.int64)
        if cls.size and cls.max() >= self.n_classes:
            bad = int(labels[cls >= self.n_classes][0])
            raise ValueError(f"predicted panoptic label {bad} has class {bad // 1000} ≥ {self.n_classes}")
        return cls

    def ids(self, labels: np.ndarray) -> np.ndarray:
        return labels.astype(np.int64)


def read_panoptic_npz(path: str | Path) -> np.ndarray:
    """Read ``{token}_panoptic.npz`` (array ``data``) as ``(N,) uint16`` panoptic labels.

    Raises:
        LabelFormatError: missing or unreadable file, no ``data`` array, or not 1-D integers < 2¹⁶.
    """
    path = Path(path)
    try:
        with np.load(path) as npz:
            if "data" not in npz.files:
                raise LabelFormatError(path, f"has no 'data' array (found {npz.files})")
            data = npz["data"]
    except (OSError, ValueError, zipfile.BadZipFile) as exc:
        raise LabelFormatError(path, f"cannot read panoptic labels: {exc}") from exc
    if data.ndim != 1 or data.dtype.kind not in "iu":
        raise LabelFormatError(path, f"'data' must be a 1-D integer array, got {data.dtype} {data.shape}")
    if data.size and (int(data.min()) < 0 or int(data.max()) > 0xFFFF):
        raise LabelFormatError(path, "'data' values must lie in [0, 65535] (class * 1000 + instance)")
    return data.astype(np.uint16)


def write_panoptic_npz(path: str | Path, labels: np.ndarray) -> None:
    """Write ``(N,)`` panoptic labels as ``{token}_panoptic.npz`` (compressed, array ``data``)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(path, data=np.asarray(labels, dtype=np.uint16))


class NuScenesCells:
    """Builds a frame's cells from nuScenes ground truth and prediction labels."""

    def __init__(self, label_map: LabelMap | None = None) -> None:
        self.label_map = label_map or load_label_map("panoptic-nuscenes")
        self.spec = ClassSpec.from_label_map(self.label_map)
        self._gt = NuScenesGtDecoder(self.label_map)
        self._pred = NuScenesPredDecoder(self.spec.n_classes)

    def __call__(self, gt: np.ndarray, pred: np.ndarray, frame: str = "") -> Cells:
        gt = check_labels(gt, "gt panoptic labels")
        pred = check_labels(pred, "pred panoptic labels")
        if gt.shape != pred.shape:
            raise ValueError(f"gt has {gt.shape[0]} labels but pred has {pred.shape[0]} (frame {frame!r})")
        return make_cells(gt, pred, self._gt, self._pred)


class NuScenesPanopticEvaluator:
    """Panoptic nuScenes segmentation scorer (``PanopticEval`` semantics, min_points 15).

    Args:
        label_map: the Panoptic nuScenes label map (default: bundled).
        min_points: minimum size of an unmatched segment (default 15).
        mode: ``official`` or ``corrected`` (identical for nuScenes labels, which fit 16 bits).
    """

    def __init__(
        self,
        label_map: LabelMap | None = None,
        min_points: int = NUSCENES_MIN_POINTS,
        mode: Mode | str = Mode.OFFICIAL,
    ) -> None:
        self.cells = NuScenesCells(label_map)
        self.spec = self.cells.spec
        self.mode = as_mode(mode)
        self.panoptic = PanopticAccumulator(self.spec, min_points, self.mode)

    def add(self, gt: np.ndarray, pred: np.ndarray, frame: str = "") -> None:
        """Score one sample: ``(N,)`` uint16 ground-truth and predicted panoptic labels."""
        self.panoptic.add(self.cells(gt, pred, frame))

    def merge(self, other: NuScenesPanopticEvaluator) -> NuScenesPanopticEvaluator:
        self.panoptic.merge(other.panoptic)
        return self

    def result(self) -> PQResult:
        return self.panoptic.result()
