"""The review folder: the least confident frames of a run as a SemanticKITTI-layout log.

::

    DIR/sequences/SS/velodyne/NNNNNN.bin    the scan, as read from the run's log
    DIR/sequences/SS/labels/NNNNNN.label    the predicted labels (raw id | instance << 16), to correct
    DIR/review.json                         source run, and per frame its confidence terms

Frame ids are the source log's, so a corrected label maps back to its scan. The folder is a log
that ``dsnet train dsnet DIR --init-from CKPT`` reads directly (single scans: no poses are written).
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dsnet_core.errors import ConfigError
from dsnet_core.io.semantickitti import write_frame

MANIFEST = "review.json"


@dataclass(frozen=True)
class ReviewFrame:
    """One frame to review.

    Attributes:
        sequence, frame_id: where it comes from.
        scan: float32 ``(N, 4)`` x, y, z (metres), remission.
        label: uint32 ``(N,)`` predicted raw semantic id | instance id << 16.
        confidence: the frame's confidence terms (see :mod:`dsnet_core.review.confidence`).
    """

    sequence: str
    frame_id: str
    scan: np.ndarray
    label: np.ndarray
    confidence: dict = field(default_factory=dict)


def write_review_folder(out: str | Path, frames: Iterable[ReviewFrame], source: dict) -> Path:
    """Write the frames and ``review.json`` (``source`` describes the run: root, checkpoint, ...).

    Raises:
        ConfigError: ``out`` already holds a review folder or scans (never overwritten), or a label
            does not match its scan.
    """
    out = Path(out)
    if (out / MANIFEST).exists() or any((out / "sequences").glob("*/velodyne/*.bin")):
        raise ConfigError(f"{out} already holds frames: choose an empty --out")
    rows = []
    for f in frames:
        if f.label.shape != (f.scan.shape[0],):
            raise ConfigError(
                f"{f.sequence}/{f.frame_id}: {f.label.shape[0]} labels for {f.scan.shape[0]} points"
            )
        write_frame(out / "sequences" / f.sequence, f.frame_id, f.scan, f.label.astype(np.uint32))
        rows.append(
            {"sequence": f.sequence, "frame": f.frame_id, "points": int(f.scan.shape[0]), **f.confidence}
        )
    out.mkdir(parents=True, exist_ok=True)
    (out / MANIFEST).write_text(json.dumps({"source": source, "frames": rows}, indent=2) + "\n")
    return out
