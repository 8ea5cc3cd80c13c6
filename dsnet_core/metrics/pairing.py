"""Pair ground-truth and prediction label files by name (never by position).

Layout (SemanticKITTI benchmark)::

    GT_ROOT/sequences/SS/labels/NNNNNN.label
    PRED_ROOT/sequences/SS/predictions/NNNNNN.label
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dsnet_core.errors import LabelFormatError, SequenceLayoutError
from dsnet_core.io import kitti
from dsnet_core.io.semantickitti import check_raw_ids
from dsnet_core.labels import LabelMap


@dataclass(frozen=True)
class LabelPair:
    """One frame to score: its sequence, name and the two label files; with ``label_map``, raw
    semantic ids the map does not know are refused in either file (as ``dsnet describe`` does)."""

    sequence: str
    frame: str
    gt_path: Path
    pred_path: Path
    label_map: LabelMap | None = None

    def read(self) -> tuple[np.ndarray, np.ndarray]:
        """``(gt, pred)`` uint32 ``(N,)`` labels.

        Raises:
            LabelFormatError: a file is unreadable or truncated, holds raw ids the label map does
                not know, or the prediction's length differs from the ground truth's (the message
                names the file).
        """
        gt = kitti.read_label(self.gt_path)
        pred = kitti.read_label(self.pred_path)
        if self.label_map is not None:
            check_raw_ids(self.gt_path, gt, self.label_map)
            check_raw_ids(self.pred_path, pred, self.label_map)
        if pred.shape != gt.shape:
            raise LabelFormatError(
                self.pred_path,
                f"has {pred.shape[0]} labels but the ground truth {self.gt_path} has {gt.shape[0]}",
            )
        return gt, pred


def sequence_names(sequences: Iterable[int | str]) -> list[str]:
    """Benchmark sequence folder names: integers become two digits (``8`` -> ``"08"``)."""
    out = []
    for s in sequences:
        text = str(s).strip()
        out.append(f"{int(text):02d}" if text.isdigit() else text)
    return out


def common_sequences(gt_root: str | Path, pred_root: str | Path) -> list[str]:
    """The sequences that have both ground-truth labels (``sequences/SS/labels/*.label``) and
    predictions (``sequences/SS/predictions/*.label``), sorted."""

    def having(root: Path, sub: str) -> set[str]:
        seqs = Path(root) / "sequences"
        if not seqs.is_dir():
            return set()
        return {p.name for p in seqs.iterdir() if p.is_dir() and any((p / sub).glob("*.label"))}

    return sorted(having(Path(gt_root), "labels") & having(Path(pred_root), "predictions"))


def pair_label_files(
    gt_root: str | Path,
    pred_root: str | Path,
    sequences: Iterable[str],
    label_map: LabelMap | None = None,
) -> list[LabelPair]:
    """List every (gt, prediction) label pair of ``sequences``, sorted by sequence then frame.

    Args:
        label_map: when given, reading a pair refuses raw ids the map does not know.

    Raises:
        SequenceLayoutError: a sequence folder is missing, has no labels, a ground-truth frame
            has no prediction, or a prediction has no ground truth (the message names the file).
    """
    gt_root, pred_root = Path(gt_root), Path(pred_root)
    pairs: list[LabelPair] = []
    for seq in sequence_names(sequences):
        gt_dir = gt_root / "sequences" / seq / "labels"
        pred_dir = pred_root / "sequences" / seq / "predictions"
        if not gt_dir.is_dir():
            raise SequenceLayoutError(gt_dir, f"ground-truth label folder of sequence {seq} does not exist")
        if not pred_dir.is_dir():
            raise SequenceLayoutError(pred_dir, f"prediction folder of sequence {seq} does not exist")
        gts = {p.stem: p for p in gt_dir.glob("*.label")}
        preds = {p.stem: p for p in pred_dir.glob("*.label")}
        if not gts:
            raise SequenceLayoutError(gt_dir, f"sequence {seq} has no ground-truth labels (*.label)")
        missing = sorted(gts.keys() - preds.keys())
        if missing:
            raise SequenceLayoutError(
                pred_dir / f"{missing[0]}.label",
                f"prediction missing for ground truth {gts[missing[0]]} "
                f"({len(missing)} missing in sequence {seq})",
            )
        extra = sorted(preds.keys() - gts.keys())
        if extra:
            raise SequenceLayoutError(
                preds[extra[0]],
                f"prediction has no ground truth {gt_dir / (extra[0] + '.label')} "
                f"({len(extra)} extra in sequence {seq})",
            )
        pairs.extend(LabelPair(seq, name, gts[name], preds[name], label_map) for name in sorted(gts))
    return pairs


def iter_pairs(pairs: Iterable[LabelPair]) -> Iterator[tuple[LabelPair, np.ndarray, np.ndarray]]:
    """Yield ``(pair, gt, pred)`` for each pair, reading the files lazily."""
    for pair in pairs:
        gt, pred = pair.read()
        yield pair, gt, pred
