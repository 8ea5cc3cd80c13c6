"""Per-frame semantic priors for D-PLS: any network's predictions, one file per scan.

Where a frame's prior is looked for, in this order (``SEQ`` the sequence, ``ID`` the reader's frame
id, e.g. ``000042``)::

    DIR/sequences/SEQ/predictions/ID.label   SemanticKITTI predictions (what ``dsnet export`` and
    DIR/sequences/SEQ/predictions/ID.npy     the SemanticKITTI tools write)
    DIR/SEQ/ID.label
    DIR/SEQ/ID.npy

- ``.label``: uint32 per point, raw semantic id in the lower 16 bits (SemanticKITTI encoding; the
  instance half is ignored), mapped to train ids through the prior's label map.
- ``.npy``: float ``(N, C)`` class probabilities (or scores) over the label map's C train ids.

Either way the rows follow the scan's point order, one per point of the scan file. Every problem is
a :class:`~dsnet_core.errors.PriorFormatError` naming the prior file (and the scan for a count
mismatch).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dsnet_core.errors import PriorFormatError
from dsnet_core.labels import LabelMap

SUFFIXES = (".label", ".npy")


def prior_candidates(root: str | Path, sequence: str, frame_id: str) -> list[Path]:
    """The paths a frame's prior may have, in the order they are tried."""
    root = Path(root)
    folders = (root / "sequences" / sequence / "predictions", root / sequence)
    return [folder / f"{frame_id}{suffix}" for folder in folders for suffix in SUFFIXES]


def find_prior(root: str | Path, sequence: str, frame_id: str) -> Path:
    """The first existing prior file of a frame.

    Raises:
        PriorFormatError: none exists (the message names the first candidate and the layouts).
    """
    candidates = prior_candidates(root, sequence, frame_id)
    for path in candidates:
        if path.is_file():
            return path
    raise PriorFormatError(
        candidates[0],
        f"no semantic prior for frame {frame_id} of sequence {sequence} (looked for "
        f"{', '.join(str(p.relative_to(root)) for p in candidates)} under {root})",
    )


def read_prior(path: str | Path, n_points: int, scan: str | Path, label_map: LabelMap) -> np.ndarray:
    """One frame's prior as float32 ``(N, C)`` class probabilities (one-hot for a ``.label`` file).

    Args:
        path: the prior file.
        n_points: points of the scan.
        scan: the scan file (named in a count mismatch).
        label_map: the prior's label map: raw ids → train ids, and C.

    Raises:
        PriorFormatError: unreadable, wrong count, unknown raw ids, wrong width or non-finite values.
    """
    path = Path(path)
    c = label_map.num_classes
    if path.suffix == ".label":
        raw = np.fromfile(path, dtype=np.uint32) if path.stat().st_size % 4 == 0 else None
        if raw is None:
            raise PriorFormatError(
                path, f"size {path.stat().st_size} B is not a whole number of uint32 labels"
            )
        _check_count(path, raw.shape[0], n_points, scan)
        sem = raw & 0xFFFF
        unknown = label_map.unknown_raw_ids(sem)
        if unknown.size:
            raise PriorFormatError(
                path,
                f"raw class ids {unknown[:10].tolist()} are not in the {label_map.name} label map "
                f"(give the prior's map with --prior-label-map NAME|YAML)",
            )
        probs = np.zeros((raw.shape[0], c), np.float32)
        probs[np.arange(raw.shape[0]), label_map.to_train(sem)] = 1.0
        return probs
    try:
        probs = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise PriorFormatError(path, f"not a readable .npy array: {exc}") from None
    if probs.ndim != 2 or probs.dtype.kind != "f":
        raise PriorFormatError(
            path, f"expected float (N, {c}) class probabilities, got {probs.dtype} {probs.shape}"
        )
    _check_count(path, probs.shape[0], n_points, scan)
    if probs.shape[1] != c:
        raise PriorFormatError(
            path, f"has {probs.shape[1]} classes per point; the {label_map.name} label map has {c} train ids"
        )
    if not np.isfinite(probs).all():
        raise PriorFormatError(path, "holds NaN or infinite probabilities")
    return probs.astype(np.float32, copy=False)


def _check_count(path: Path, found: int, n_points: int, scan: str | Path) -> None:
    if found != n_points:
        raise PriorFormatError(
            path,
            f"has {found} points but its scan {scan} has {n_points}: a prior must follow the scan's points",
        )


def prior_classes(probs: np.ndarray) -> np.ndarray:
    """The prior's class per point: argmax over train ids 1..C-1 (0 where a row is all zero, i.e.
    a one-hot ``unlabelled`` row or no information)."""
    if probs.shape[0] == 0:
        return np.zeros(0, np.int64)
    best = probs[:, 1:].argmax(1) + 1
    return np.where(probs[:, 1:].max(1) > 0, best, 0).astype(np.int64)
