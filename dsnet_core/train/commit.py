"""An epoch's checkpoint files land together or not at all: a small redo log in the folder.

The trainer writes every file of an epoch (weights, shifting weights, card, optimiser state,
metrics) into ``CKPT/.pending/``, then the marker ``.pending/COMMIT`` listing them (the commit
point, written atomically), then moves each file into place and removes the folder.
:func:`recover`, run before a checkpoint folder is resumed, finishes the moves of a committed
epoch and throws an uncommitted one away. A kill at any moment therefore leaves the previous
epoch or the new one, never a mix of the two (weights of one epoch with the optimiser state or
card of another), and a resumed run continues bit-identically.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

PENDING, COMMIT = ".pending", "COMMIT"


def begin(out: str | Path) -> Path:
    """A fresh, empty staging folder ``out/.pending`` for the next epoch's files."""
    staging = Path(out) / PENDING
    if staging.exists():
        shutil.rmtree(staging)
    staging.mkdir(parents=True)
    return staging


def commit(out: str | Path) -> None:
    """Make the staged files the checkpoint: write the commit marker, then move them into place."""
    staging = Path(out) / PENDING
    names = sorted(p.name for p in staging.iterdir() if p.is_file() and p.name != COMMIT)
    tmp = staging / (COMMIT + ".tmp")
    tmp.write_text(json.dumps(names))
    os.replace(tmp, staging / COMMIT)
    _roll_forward(Path(out), names)


def recover(out: str | Path) -> str | None:
    """Bring ``out`` to its last committed epoch.

    Returns:
        ``"rolled forward"`` (a committed epoch's moves were finished), ``"rolled back"`` (an
        uncommitted epoch's files were discarded), or None when there was nothing to do.
    """
    out = Path(out)
    staging = out / PENDING
    if not staging.is_dir():
        return None
    marker = staging / COMMIT
    if marker.is_file():
        _roll_forward(out, json.loads(marker.read_text()))
        return "rolled forward"
    shutil.rmtree(staging)
    return "rolled back"


def _roll_forward(out: Path, names: list[str]) -> None:
    staging = out / PENDING
    for name in names:
        src = staging / name
        if src.is_file():  # already moved when a previous roll-forward was interrupted
            os.replace(src, out / name)
    shutil.rmtree(staging)
