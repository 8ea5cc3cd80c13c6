"""Stage ``track``: sequence-wide instance ids by tracking each frame's instances over time.

The alternative to ``stitch`` (``dsnet label --temporal track``; the default at k = 1, where
volumes share no frame and stitching can only hand out fresh ids). Frames are visited in order;
each frame's instances come from the first volume that contains it (``stitch``'s ownership rule),
restricted to that frame's points. Their centroids, taken into the world frame with the volume's
reference pose, go through :class:`dsnet_core.temporal.tracking.Tracker`: greedy association to
the live tracks displaced by their constant velocity, gated by distance and by the label map's
track groups, a birth for every unmatched instance and a maximum age for unseen tracks; ids from
one counter per sequence. Beyond the 65 535 ids of a label, ids no track has held for more than
``id_reuse_after`` frames are reused, as in ``stitch`` (a warning once per sequence, ``ids_reused``
in the manifest's counts).

Output as ``stitch``: per frame ``label`` uint32 in the scan's ORIGINAL point order (raw semantic |
id << 16 in the model's label map); quarantined frames get none. Table ``tracked``: one row per
track (per hand-out of an id: ``generation``).

Tracking is sequential: a sequence is one block, resumable inside it. After each frame is
written the tracker's state is saved as the stage's state (tagged with the fingerprint and the
frame's position), so a killed run continues after the last saved frame to identical labels.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator

import numpy as np
import pyarrow as pa
from pydantic import Field

from dsnet_core.temporal.ids import REUSE_AFTER, key_generation, key_id
from storage.contract import TableSpec
from tasks.align import sequential_frames_plan
from tasks.base import FRAME_LABEL, ItemResult, Plan, Stage, StageConfig, StageContext, StateThrottle
from tasks.track_ids import warn_reuse

log = logging.getLogger(__name__)


class TrackConfig(StageConfig):
    """Association settings (:class:`dsnet_core.temporal.tracking.Tracker`).

    Attributes:
        max_distance: association gate between a track's predicted and an instance's centroid, m.
        max_age: frames a track may go unseen and still be matched.
        constant_velocity: predict a track's position with its last velocity.
        id_reuse_after: once the 65 535 ids of a label are used up, an id is handed out again only
            after this many frames without a track holding it (keep it above refine's ``join_gap``).
    """

    max_distance: float = Field(2.0, gt=0)
    max_age: int = Field(2, ge=0)
    constant_velocity: bool = True
    id_reuse_after: int = Field(REUSE_AFTER, ge=1)


TRACKED = TableSpec(
    "tracked",
    pa.schema(
        [
            ("id", pa.int32()),  # sequence-wide instance id (upper 16 bits of the label)
            ("generation", pa.int32()),  # which hand-out of the id (0; 1, 2, ... once ids are reused)
            ("class_id", pa.int32()),  # train id of the track's first sighting
            ("raw_class", pa.int32()),  # the same through learning_map_inv
            ("first_frame", pa.int32()),  # frame indices (the ingest frame table's ``index``)
            ("last_frame", pa.int32()),
            ("n_points", pa.int64()),
            ("n_frames", pa.int32()),
            ("frames", pa.list_(pa.int32())),  # frames the track has points in
            ("frame_points", pa.list_(pa.int64())),  # its points in each of those frames
        ]
    ),
    roles=(("id", "id"), ("generation", "generation"), ("class_id", "class_id"), ("points", "n_points"),
           ("item", "first_frame")),
)  # fmt: skip


INSTANCE_ARRAYS = ("sem", "inst")
"""What ``track`` follows: a stage's per-volume class and volume-local instance id."""
DETECTIONS = "detections"
"""A source table of per-volume detections (id, class, centre, velocity): when the source declares
one (MOST), tracks follow its centres and learned velocities instead of instance centroids."""


class TrackStage(Stage):
    """Tracks the instances of ``source`` (any stage declaring :data:`INSTANCE_ARRAYS`): by their
    centroids with a constant-velocity model (fused instances), or, when the source declares a
    :data:`DETECTIONS` table, by its detections' centres and learned velocities (MOST)."""

    name = "track"
    version = "2"  # 2: ids reused beyond 65 535, the tracked table's generation
    Config = TrackConfig
    item = "frame"
    arrays = (FRAME_LABEL,)
    tables = (TRACKED,)

    def __init__(self, source: str = "fuse") -> None:
        self.source = source
        self.upstream = (source, "align")

    def check_sources(self, pipeline) -> None:
        self.require(pipeline, self.source, INSTANCE_ARRAYS)

    def plan(self, ctx: StageContext) -> Plan:
        return sequential_frames_plan(ctx)

    def run_block(self, ctx: StageContext, items: list[int]) -> Iterator[ItemResult]:
        from dsnet_core.temporal.tracking import Tracker, instance_centroids, relabel

        todo = set(items)
        if not todo:
            return
        label_map = ctx.label_map
        thing_of = label_map.is_thing()
        values = ctx.frame_values()
        order = values.frames()
        frames = ctx.frames.to_pydict()
        pose = dict(zip(frames["index"], frames["pose"], strict=True))
        stamp = dict(zip(frames["index"], frames["timestamp"], strict=True))
        refs = _ref_frames(ctx)
        frame_points = ctx.plan["frame_points"]
        fingerprint = ctx.manifest(self.name).fingerprint
        tracker, start, summary = self._resume(ctx, fingerprint, order, label_map)
        if tracker is None:
            c = ctx.config
            tracker = Tracker(
                label_map,
                max_distance=c.max_distance,
                max_age=c.max_age,
                constant_velocity=c.constant_velocity,
                reuse_after=c.id_reuse_after,
            )
        else:
            log.info("track %s resumes after frame %d from its saved state", ctx.sequence, order[start - 1])
        align, instances = ctx.arrays("align"), ctx.arrays(self.source)
        has_detections = any(t.name == DETECTIONS for t in ctx.pipeline[self.source].tables)
        detections = _detections(ctx, self.source) if has_detections else None
        throttle = StateThrottle()
        warned = False
        for k in range(start, len(order)):
            f = order[k]
            v = values.owner[f]
            vol = values.frame(align, f, ["points"])
            found = values.frame(instances, f, ["sem", "inst"])
            xyz = vol["points"][:, :3]
            sem = found["sem"].astype(np.int64)
            inst = found["inst"].astype(np.int64)
            thing = thing_of[sem]
            ref = refs[v]
            world = None if pose.get(ref) is None else np.asarray(pose[ref], np.float64).reshape(4, 4)
            time = stamp.get(f)
            if detections is None:
                ids, cent, cls = instance_centroids(xyz, sem, inst, thing)
                tid = tracker.add_detections(cent, cls, world, time if time is not None else float(f))
            else:  # MOST: modal centres with learned velocities (m/s: frames without stamps at 10 Hz)
                ids, cent, cls, vel = _frame_detections(detections, v, inst)
                tid = tracker.add_detections(cent, cls, world, time if time is not None else 0.1 * f, vel)
            warned = warn_reuse(ctx.sequence, self.name, tracker.ids, f, warned)
            label = np.zeros(int(frame_points[f]), np.uint32)
            label[: sem.shape[0]] = relabel(label_map, sem, inst, ids, tid, thing)
            _summarise(summary, f, label, tid, cls)
            if f in todo:
                rows, counts = {}, {}
                if k == len(order) - 1:
                    rows = {"tracked": _track_rows(summary, label_map)}
                    counts = {"tracks": len(rows["tracked"]), "ids_reused": tracker.ids.reused}
                n = int(label.shape[0])
                yield ItemResult(
                    f,
                    arrays={"label": label},
                    n_points=n,
                    rows=rows,
                    counts={"frames": 1, "points": n, "tracks": 0, "ids_reused": 0} | counts,
                )
            if k < len(order) - 1 and throttle.due():
                with throttle:
                    ctx.store.write_stage_state(
                        ctx.sequence,
                        self.name,
                        {
                            "fingerprint": fingerprint,
                            "position": k,
                            "state": tracker.state_dict(),
                            "summary": summary,
                        },
                    )
        ctx.store.write_stage_state(ctx.sequence, self.name, None)

    def _resume(self, ctx: StageContext, fingerprint: str, order: list[int], label_map):
        """(tracker, first position to compute, summary) from a valid saved state, else a fresh start."""
        from dsnet_core.temporal.tracking import Tracker

        saved = ctx.store.read_stage_state(ctx.sequence, self.name)
        done = ctx.arrays(self.name).done()
        if saved is None or saved.get("fingerprint") != fingerprint:
            return None, 0, {}
        k = int(saved["position"])
        if k >= len(order) - 1 or not done[order[: k + 1]].all():
            return None, 0, {}
        summary = {int(i): row for i, row in saved["summary"].items()}
        return Tracker.from_state(saved["state"], label_map), k + 1, summary


def _detections(ctx: StageContext, source: str) -> dict[int, dict[str, np.ndarray]]:
    """The source's :data:`DETECTIONS` table by volume: ids, centres, classes, velocities."""
    t = ctx.table(source, DETECTIONS)
    index = t["index"].to_numpy()
    cols = {
        "id": t["id"].to_numpy().astype(np.int64),
        "class_id": t["class_id"].to_numpy().astype(np.int64),
        "centre": np.asarray(t["centre"].to_pylist(), np.float64).reshape(-1, 3),
        "velocity": np.asarray(t["velocity"].to_pylist(), np.float64).reshape(-1, 2),
    }
    return {int(v): {k: c[index == v] for k, c in cols.items()} for v in np.unique(index)}


def _frame_detections(detections: dict, volume: int, inst: np.ndarray):
    """One frame's detections that own points: ids, centres ``(M, 3)``, classes, velocities ``(M, 2)``."""
    d = detections.get(volume)
    if d is None:
        return np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0, np.int64), np.zeros((0, 2))
    keep = np.isin(d["id"], inst[inst > 0])
    return d["id"][keep], d["centre"][keep], d["class_id"][keep], d["velocity"][keep]


def _ref_frames(ctx: StageContext) -> dict[int, int]:
    """Volume index → the frame whose sensor frame its points are in."""
    t = ctx.table("align", "volumes").to_pydict()
    return {int(i): int(r) for i, r in zip(t["index"], t["ref_frame"], strict=True)}


def _summarise(summary: dict, frame: int, label: np.ndarray, tid: np.ndarray, cls: np.ndarray) -> None:
    """Add one frame's tracked instances to ``summary`` (track key → JSON-able row parts)."""
    ids, counts = np.unique(label >> 16, return_counts=True)
    points = {int(i): int(c) for i, c in zip(ids.tolist(), counts.tolist(), strict=True) if i}
    for t, c in zip(tid.tolist(), cls.tolist(), strict=True):
        n = points.get(int(key_id(t)), 0)
        if n == 0:
            continue
        row = summary.setdefault(int(t), {"class_id": int(c), "frames": [], "frame_points": []})
        row["frames"].append(int(frame))
        row["frame_points"].append(n)


def _track_rows(summary: dict, label_map) -> list[dict]:
    """The ``tracked`` table's rows, one per track (hand-out of an id), sorted by (id, generation)."""
    rows = []
    for key in sorted(summary, key=lambda t: (key_id(t), t)):
        r = summary[key]
        rows.append(
            {
                "id": key_id(key),
                "generation": key_generation(key),
                "class_id": r["class_id"],
                "raw_class": int(label_map.to_raw(np.asarray([r["class_id"]]))[0]),
                "first_frame": min(r["frames"]),
                "last_frame": max(r["frames"]),
                "n_points": int(sum(r["frame_points"])),
                "n_frames": len(r["frames"]),
                "frames": r["frames"],
                "frame_points": r["frame_points"],
            }
        )
    return rows
