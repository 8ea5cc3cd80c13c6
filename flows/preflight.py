"""What ``dsnet label`` checks of a log's content and its model before any server or stage starts.

:meth:`flows.request.LabelRequest.check` opens the log (its format, its layout) and validates the
stage configs; :func:`check_content` goes on to what ``dsnet describe`` would find in seconds, so
that a bad log is one line in about a second, not a Prefect server's start and the same error
from three task reports:

- volumes of k ≥ 2 scans from a log without poses (and without ``--estimate-poses``);
- each sequence's first and last scan and their labels read as ingest reads them (the first
  :data:`SAMPLED_SEQUENCES` sequences the run labels; a PCD whose
  header contradicts itself, a truncated file, inf coordinates, labels of the wrong length) — only
  with ``--on-error fail``: with ``skip`` a bad frame is quarantined, not refused. Other frames are
  read by ingest (a whole-log check would read every scan twice);
- a semantics-only checkpoint (an imported Cylinder3D network), whose instance head is untrained:
  refused for instance labelling, saying how to train the head; a checkpoint whose weights (or
  shifting weights) are missing or not the ones its card records (their sha256), naming the file.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

SAMPLED_SEQUENCES = 8
"""Sequences whose first and last scans are read (the first ones of the run: a log of hundreds of
sequences is not read twice before its run starts)."""


def check_content(request: Any, sequences: list[str] | None = None) -> None:
    """Refuse a request whose log content or model would fail the run, naming the file.

    Args:
        request: a :class:`~flows.request.LabelRequest` (after its :meth:`check`).
        sequences: the sequences the run will label (default: the request's, else the log's).

    Raises:
        DataFormatError: a sampled scan or label file that does not read, or poses missing for k ≥ 2.
        CheckpointError: a semantics-only checkpoint.
    """
    check_checkpoint(request.stages)
    reader = request.open_log()
    stages = request.stages
    scans = int(stages.get("align", {}).get("scans", 1))
    estimate = bool(stages.get("ingest", {}).get("estimate_poses", False))
    skip = getattr(request.options, "on_error", "fail") == "skip"
    known = set(reader.sequences())
    todo = sequences if sequences is not None else (request.sequences or reader.sequences())
    for n, seq in enumerate(s for s in todo if s in known):  # the store names an unknown one
        frames = reader.frames(seq)
        if scans > 1 and not estimate and frames and reader.poses(seq) is None:
            from dsnet_core.errors import PoseFormatError

            raise PoseFormatError(
                Path(frames[-1].scan_path).parent,
                f"sequence {seq}: volumes of --scans {scans} need poses and the log has none (estimate "
                "them with KISS-ICP: dsnet label --estimate-poses, or label with --scans 1)",
            )
        if skip or n >= SAMPLED_SEQUENCES:
            continue
        for ref in {id(f): f for f in (frames[:1] + frames[-1:])}.values():
            reader.scan(ref)
            reader.labels(ref)


def check_checkpoint(stages: dict[str, dict[str, Any]]) -> None:
    """Refuse a semantics-only checkpoint for labelling (its instance head was never trained).

    Raises:
        CheckpointError: naming the card and the command that trains the instance head.
    """
    path = stages.get("infer", {}).get("checkpoint")
    if not path:
        return
    from dsnet_core.errors import CheckpointError
    from dsnet_core.model.card import CARD, card_json, check_card_files

    card = Path(path) / CARD
    if not card.is_file():
        return  # the stage config's own checks name a missing card
    check_card_files(path)  # damaged or lost weights: one line now, not a failed infer stage later
    imported = (card_json(path).get("training_data") or {}).get("imported") or {}
    if imported.get("semantic_only"):
        raise CheckpointError(
            card,
            f"semantics only (an imported {imported.get('kind', 'cylinder3d')} network): its instance "
            "head is untrained, so its instances would be random: train the instance head with "
            f"dsnet train dsnet DATA --init-from {path} --out NEW, and label with --checkpoint NEW",
        )
