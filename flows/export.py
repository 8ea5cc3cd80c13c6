"""Export a run store's final labels (its method's labels stage) in the log's own terms.

The output formats carry the input formats' names (``dsnet label --format`` and ``dsnet export
--format`` agree), and a run exports in its log's format unless told otherwise:

* ``semantickitti``: ``OUT/sequences/SS/predictions/<frame>.label`` -- what ``dsnet eval --pred
  OUT`` and the SemanticKITTI benchmark read;
* ``folder``: ``OUT/<sequence>/<scan name>.label``, one per scan file (``scan_0001.pcd`` ->
  ``scan_0001.label``; the folder reader takes labels from ``<scan>.label`` or ``labels/``);
* ``rosbag``: ``OUT/<bag>/<header stamp ns>.label``, one per PointCloud2 message;
* ``nuscenes``: the devkit's results layout keyed by the log's own sample_data tokens
  (:mod:`flows.export_nuscenes`).

A ``.label`` is uint32 per point in the scan's own order: raw semantic id of the model's label map
(``learning_map_inv``) | instance << 16. Frame names come from the ingest frame table (a folder
scan's stem, a bag message's stamp). Plain functions: no Prefect.

The formats are registered in :mod:`flows.export_formats`, which ``dsnet export`` looks them up in.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from storage.errors import DamagedStoreError, StoreError
from storage.run import RunStore
from tasks.base import labels_contract
from tasks.ingest import FRAMES, IngestStage
from tasks.run_config import read_run


@dataclass
class ExportSummary:
    """What an export wrote.

    Attributes:
        out: the predictions root.
        frames: sequence -> number of label files written.
        missing: sequence -> frame ids without a final label (quarantined frames).
        removed: sequence -> names of the ``.label`` files an earlier export left in the
            sequence's folder for frames this one does not write (removed: a scorer would read them
            as this run's).
    """

    out: Path
    frames: dict[str, int] = field(default_factory=dict)
    missing: dict[str, list[str]] = field(default_factory=dict)
    removed: dict[str, list[str]] = field(default_factory=dict)

    def sweep(self, seq: str, folder: Path, written: set[str]) -> None:
        """Remove the ``.label`` files in ``folder`` that are not ``written`` by this export."""
        stale = (
            sorted(p.name for p in folder.glob("*.label") if p.name not in written) if folder.is_dir() else []
        )
        for name in stale:
            (folder / name).unlink()
        self.removed[seq] = stale


def final_labels(
    store: RunStore, sequences: list[str] | None = None
) -> Iterator[tuple[str, str, np.ndarray | None]]:
    """Yield ``(sequence, frame_id, label)`` for every frame of every sequence whose labels stage (the
    run's method's: ``stitch`` for DS-Net) is done.

    ``label`` is uint32 ``(N,)`` (raw semantic | instance << 16) or None for a frame without a final
    label (quarantined). Sequences are visited in sorted order, frames in ingest order.

    Raises:
        StoreError: a requested sequence has no finished labels stage, or none has.
        DamagedStoreError: a label chunk (or the frame table) is missing, truncated or differs from
            what was written (the store's cheap check before the first frame, then each frame's
            digests as it is read): never a label made of fill values.
    """
    run = read_run(store)
    contract = labels_contract(run.labels())
    if sequences is not None:
        known = sorted(set(store.sequences()) | set(run.sequences))
        unknown = [s for s in sequences if s not in known]
        if unknown:
            raise StoreError(
                store.uri,
                f"the run has no sequence {', '.join(map(repr, unknown))} "
                f"(it has {', '.join(known) or 'none'})",
            )
    found = False
    for seq in sorted(sequences if sequences is not None else store.sequences()):
        m = store.read_manifest(seq, contract.stage)
        if m is None or m.status != "done":
            if sequences is not None:
                raise StoreError(store.where(seq, contract.stage), f"stage {contract.stage!r} is not done")
            continue
        found = True
        damage = store.check_stage(seq, contract, m)
        if damage:
            raise damage[0].error()
        try:
            ids = store.read_table(seq, FRAMES)["frame_id"].to_pylist()
            arrays = store.arrays(seq, contract)
            done = arrays.done()
            for index, frame_id in enumerate(ids):
                if not done[index]:
                    arrays.check_not_done(index)  # quarantined, or its done flag was lost
                    yield seq, frame_id, None
                    continue
                yield seq, frame_id, arrays.read_item(index, ["label"])["label"]
        except DamagedStoreError as exc:  # noted, so that the rerun it asks for repairs it
            store.note_found(exc.where, exc.problem)
            raise
    if not found:
        raise StoreError(store.uri, f"no sequence has a finished {contract.stage!r} stage to export")


def export_semantickitti(
    root: str, out: str | Path, sequences: list[str] | None = None, storage_options: dict | None = None
) -> ExportSummary:
    """Write ``out/sequences/SS/predictions/*.label`` for every sequence whose labels stage is done.

    Raises:
        StoreError: a requested sequence (or, with none requested, every sequence) has no
            finished labels stage.
    """
    from dsnet_core.io.kitti import write_label

    store = RunStore(root, storage_options)
    out = Path(out)
    summary = ExportSummary(out=out)
    written: dict[str, set[str]] = {}
    for seq, frame_id, label in final_labels(store, sequences):
        summary.frames.setdefault(seq, 0)
        summary.missing.setdefault(seq, [])
        written.setdefault(seq, set())
        if label is None:
            summary.missing[seq].append(frame_id)
            continue
        write_label(out / "sequences" / seq / "predictions" / f"{frame_id}.label", label)
        written[seq].add(f"{frame_id}.label")
        summary.frames[seq] += 1
    for seq, names in written.items():
        summary.sweep(seq, out / "sequences" / seq / "predictions", names)
    return summary


def export_frames(
    root: str, out: str | Path, sequences: list[str] | None = None, storage_options: dict | None = None
) -> ExportSummary:
    """Write ``out/<sequence>/<frame id>.label`` for every sequence whose labels stage is done (the
    ``folder`` and ``rosbag`` layouts: a scan's file stem, or a bag message's stamp in ns).

    Raises:
        StoreError: as :func:`export_semantickitti`.
    """
    from dsnet_core.io.kitti import write_label

    store = RunStore(root, storage_options)
    out = Path(out)
    summary = ExportSummary(out=out)
    source = _SourcePoints(store)
    written: dict[str, set[str]] = {}
    for seq, frame_id, label in final_labels(store, sequences):
        summary.frames.setdefault(seq, 0)
        summary.missing.setdefault(seq, [])
        written.setdefault(seq, set())
        if label is None:
            summary.missing[seq].append(frame_id)
            continue
        write_label(out / seq / f"{frame_id}.label", source.expand(seq, frame_id, label))
        written[seq].add(f"{frame_id}.label")
        summary.frames[seq] += 1
    for seq, names in written.items():
        summary.sweep(seq, out / seq, names)
    return summary


class _SourcePoints:
    """Puts back the points a reader dropped as no returns (ingest's ``no_return``), unlabelled, so
    a ``.label`` has one entry per point of the source scan or message, in its order. Only frames
    that had such points open the log (through the run's format and reader options)."""

    def __init__(self, store: RunStore) -> None:
        self.store = store
        self.dropped: dict[str, dict[str, int]] = {}
        self.reader = None
        self.refs: dict[str, dict] = {}

    def expand(self, seq: str, frame_id: str, label: np.ndarray) -> np.ndarray:
        if seq not in self.dropped:
            table = self.store.read_table(seq, FRAMES).to_pydict()
            counts = table.get("no_return") or [0] * len(table["frame_id"])
            self.dropped[seq] = dict(zip(table["frame_id"], counts, strict=True))
        if not self.dropped[seq].get(frame_id):
            return label
        if self.reader is None:
            self.reader = read_run(self.store).open_log()
        if seq not in self.refs:
            self.refs[seq] = {f.frame_id: f for f in self.reader.frames(seq)}
        keep = self.reader.kept_points(self.refs[seq][frame_id])
        if keep is None or int(keep.sum()) != len(label):
            raise StoreError(
                self.store.where(seq, IngestStage.name),
                f"frame {frame_id}: the log's scan no longer matches the run's ({len(label)} labelled "
                "points); relabel it",
            )
        full = np.zeros(keep.shape[0], dtype=np.uint32)
        full[keep] = label
        return full
