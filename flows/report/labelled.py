"""What a run labelled, with or without ground truth: one read of every frame's final labels.

Per frame the points of each class and the instance ids present; per sequence the tracks (an
instance id of the final labels over the frames it appears in — one per hand-out of the id where
the temporal stage reused ids, told apart by its track table's ``generation`` — its class the one
of most of its points); per class the points, frames and tracks, and the model's confidence in the class
(:class:`~flows.report.confidence.ConfidencePass`). Where the ``refine`` stage ran, its
``refine_changes`` table gives the points it changed per frame and the class shares before it
(after + what left a class − what entered it), and its plan the tracks it joined and dissolved.
Only declared arrays and tables are read: the labels stage's ``label``
(:data:`tasks.base.FRAME_LABEL`), ingest's frame table, refine's tables.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from dsnet_core.labels import LabelMap
from flows.report.confidence import ConfidencePass
from storage.run import RunStore
from tasks.base import labels_contract
from tasks.ingest import IngestStage
from tasks.pipeline import Pipeline
from tasks.refine import CHANGES, RefineStage
from tasks.score import ScoreStage
from tasks.track_ids import track_generations


@dataclass
class LabelSummary:
    """The rows of the labelling report's per-sequence tables (:mod:`flows.report.label_tables`)."""

    sequences: list[dict[str, Any]] = field(default_factory=list)
    classes: list[dict[str, Any]] = field(default_factory=list)
    frames: list[dict[str, Any]] = field(default_factory=list)
    tracks: list[dict[str, Any]] = field(default_factory=list)
    transitions: list[dict[str, Any]] = field(default_factory=list)


def _done(store: RunStore, seq: str, stage: str):
    m = store.read_manifest(seq, stage)
    return m if m is not None and m.status == "done" else None


def summarise(
    store: RunStore, pipeline: Pipeline, sequences: list[str], label_map: LabelMap, conf: ConfidencePass
) -> LabelSummary:
    """The labelling report's rows of every sequence whose labels stage is done.

    Args:
        label_map: the model's label map (the final labels' encoding).
        conf: the run's frame and class confidences (empty for methods without them).
    """
    out = LabelSummary()
    for seq in sequences:
        labels = _done(store, seq, pipeline.labels)
        if labels is None or _done(store, seq, IngestStage.name) is None:
            continue
        _sequence(store, pipeline, seq, labels.fingerprint, label_map, conf, out)
    return out


def _sequence(
    store: RunStore,
    pipeline: Pipeline,
    seq: str,
    fingerprint: str,
    label_map: LabelMap,
    conf: ConfidencePass,
    out: LabelSummary,
) -> None:
    frames = store.read_table(seq, pipeline[IngestStage.name].table("frames")).to_pydict()
    arrays = store.arrays(seq, labels_contract(pipeline.labels))
    done = arrays.done()
    lut = label_map.lut(1 << 16, fill=0)
    n_classes = label_map.num_classes
    refine = _refine_changes(store, pipeline, seq)
    confidence = {r["index"]: r for r in conf.rows if r["sequence"] == seq}
    totals = np.zeros(n_classes, np.int64)
    present = np.zeros(n_classes, np.int64)
    tracks: dict[int, dict[str, Any]] = {}  # by track key (id | generation << 16)
    generations = track_generations(store, seq, pipeline[pipeline.labels])
    labelled = points = 0
    for index, fid, status, npts in zip(
        frames["index"], frames["frame_id"], frames["status"], frames["n_points"], strict=True
    ):
        index = int(index)
        ok = status == "ok" and index < done.size and bool(done[index])
        row = {
            "sequence": seq,
            "index": index,
            "frame_id": str(fid),
            "status": str(status),
            "labelled": ok,
            "n_points": int(npts),
            "class_points": [],
            "instances": 0,
            "changed": refine["changed"].get(index) if refine else None,
            "semantic": confidence[index]["semantic"] if index in confidence else None,
            "score": confidence[index]["score"] if index in confidence else None,
        }
        if ok:
            label = arrays.read_item(index, ["label"])["label"]
            sem = lut[label & 0xFFFF].astype(np.int64)
            inst = generations.keys((label >> 16).astype(np.int64), index)
            counts = np.bincount(sem, minlength=n_classes)[:n_classes]
            totals += counts
            present += counts > 0
            row["class_points"] = counts.tolist()
            row["instances"] = _add_tracks(tracks, index, sem, inst, n_classes)
            labelled += 1
            points += int(label.size)
        out.frames.append(row)
    track_class = _track_rows(seq, tracks, out.tracks)
    c_points, c_sum = conf.classes.get(seq, (np.zeros(0, np.int64), np.zeros(0)))
    before = _before(totals, refine["transitions"]) if refine else None
    for c in range(n_classes):
        row = {
            "sequence": seq,
            "class_id": c,
            "points": int(totals[c]),
            "points_before": None if before is None else int(before[c]),
            "frames": int(present[c]),
            "tracks": int((track_class == c).sum()),
            "confidence_points": int(c_points[c]) if c < c_points.size else 0,
            "confidence_sum": float(c_sum[c]) if c < c_sum.size else 0.0,
        }
        if row["points"] or row["points_before"] or row["confidence_points"]:
            out.classes.append(row)
    if refine:
        out.transitions += [
            {"sequence": seq, "from_id": a, "to_id": b, "points": n}
            for (a, b), n in sorted(refine["transitions"].items())
        ]
    has_conf = c_points.size > 0 and int(c_points.sum()) > 0
    plan = refine["plan"] if refine else {}
    out.sequences.append(
        {
            "sequence": seq,
            "frames": len(frames["index"]),
            "labelled": labelled,
            "quarantined": sum(s != "ok" for s in frames["status"]),
            "points": points,
            "truth_frames": int(sum(bool(h) for h in frames["has_labels"])),
            "scored": _scored(store, seq),
            "tracks": len(tracks),
            "refined": bool(refine),
            "changed": sum(refine["changed"].values()) if refine else None,
            "class_changed": sum(refine["transitions"].values()) if refine else None,
            "tracks_before": plan.get("tracks") if refine else None,
            "tracks_joined": plan.get("joins") if refine else None,
            "tracks_dissolved": plan.get("dissolved") if refine else None,
            "confidence_points": int(c_points.sum()) if has_conf else 0,
            "confidence": float(c_sum.sum() / c_points.sum()) if has_conf else None,
            "labels_fingerprint": fingerprint,
        }
    )


def _add_tracks(
    tracks: dict[int, dict], index: int, sem: np.ndarray, inst: np.ndarray, n_classes: int
) -> int:
    """Add one frame's instance points to ``tracks`` (track key -> frames, points, points per class);
    the number of instance ids in the frame."""
    sel = inst > 0
    keys, counts = np.unique(inst[sel] * n_classes + sem[sel], return_counts=True)
    ids = keys // n_classes
    for key, n in zip(keys.tolist(), counts.tolist(), strict=True):
        t = tracks.setdefault(
            key // n_classes, {"first": index, "last": index, "frames": set(), "classes": {}}
        )
        t["last"] = max(t["last"], index)
        t["frames"].add(index)
        cls = key % n_classes
        t["classes"][cls] = t["classes"].get(cls, 0) + n
    return int(np.unique(ids).size)


def _track_rows(seq: str, tracks: dict[int, dict], rows: list[dict[str, Any]]) -> np.ndarray:
    """Append one row per track, sorted by (id, generation); the class of each, ``(T,) int64``."""
    classes = []
    for tid in sorted(tracks, key=lambda k: (k & 0xFFFF, k)):
        t = tracks[tid]
        cls = max(t["classes"].items(), key=lambda kv: (kv[1], -kv[0]))[0]  # most points, then lowest id
        classes.append(cls)
        rows.append(
            {
                "sequence": seq,
                "id": int(tid) & 0xFFFF,
                "generation": int(tid) >> 16,
                "class_id": int(cls),
                "first_frame": int(t["first"]),
                "last_frame": int(t["last"]),
                "n_frames": len(t["frames"]),
                "n_points": int(sum(t["classes"].values())),
            }
        )
    return np.asarray(classes, np.int64)


def _refine_changes(store: RunStore, pipeline: Pipeline, seq: str) -> dict[str, Any] | None:
    """Refine's per-frame changed points, class transitions summed over the sequence and its plan's
    track decisions; None where the final labels are not a finished refine stage's."""
    if not isinstance(pipeline[pipeline.labels], RefineStage):
        return None
    m = _done(store, seq, pipeline.labels)
    if m is None:
        return None
    t = store.read_table(seq, CHANGES).to_pydict()
    transitions: dict[tuple[int, int], int] = {}
    for fr, to, n in zip(t["from_class"], t["to_class"], t["transitions"], strict=True):
        for a, b, k in zip(fr, to, n, strict=True):
            transitions[(int(a), int(b))] = transitions.get((int(a), int(b)), 0) + int(k)
    changed = {int(i): int(c) for i, c in zip(t["index"], t["changed"], strict=True)}
    return {"changed": changed, "transitions": transitions, "plan": m.plan}


def _before(after: np.ndarray, transitions: dict[tuple[int, int], int]) -> np.ndarray:
    """Points per class before refinement: after, plus what left each class, minus what entered it."""
    before = after.copy()
    for (a, b), n in transitions.items():
        if a != b:
            before[a] += n
            before[b] -= n
    return before


def _scored(store: RunStore, seq: str) -> bool:
    m = _done(store, seq, ScoreStage.name)
    return m is not None and m.n_items > 0
