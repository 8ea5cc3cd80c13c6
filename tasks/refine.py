"""Stage ``refine``: offline refinement of a whole sequence's final labels (:mod:`dsnet_core.refine`).

Reads the per-frame ``label`` array (:data:`~tasks.base.FRAME_LABEL`) of the temporal stage it is
built with (``RefineStage(labels="stitch")``), that stage's instance confidences where one of its
tables declares them (the ``id`` and ``confidence`` roles), the class probabilities of the nearest
upstream stage that declares infer's ``probs`` array (mapped to frames through the stage declaring
align's ``source_frame`` / ``source_index``; without one, hard labels vote one-hot, weighted by
the instance confidence), each frame's points from the log's reader and the ingest poses.
Writes per frame a refined ``label`` (same encoding and point order), a ``refine_changes`` row
(points changed and by which step, from -> to class counts, tracks joined and dissolved) and,
once, the ``refine_tracks`` table (one row per track after joins).

Two passes. ``plan`` reads every frame once and decides the tracks (one class per track, joins,
dissolving, motion): the decisions are small and live in the plan. Each block then refines its
frames from the plan and the frames within ±W of them (windowed reads of the upstream stages
only, never of other blocks' outputs), so blocks run in any order or in parallel, a killed block
resumes to identical labels, and a frame's labels do not depend on where the blocks split.
Quarantined frames and frames the temporal stage did not label get no label.

Where the temporal stage reused ids (beyond the 65 535 of a label, :mod:`dsnet_core.temporal.ids`),
its track table's ``generation`` (the roles of :data:`tasks.track_ids.GENERATION_ROLES`) tells the
tracks of one id apart: refinement works on track keys, refuses joins that would stretch an id
over another track holding it (``joins_refused`` in the plan), and ``refine_tracks`` has one row
per (id, generation).
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pyarrow as pa
from pydantic import Field

from storage.contract import TableSpec
from storage.errors import StoreError
from tasks.base import FRAME_LABEL, ItemResult, Plan, Stage, StageConfig, StageContext
from tasks.confidence import PROBS
from tasks.frames import SOURCE
from tasks.track_ids import track_generations


class RefineConfig(StageConfig):
    """Refinement settings (:mod:`dsnet_core.refine.params` has their meaning).

    Attributes:
        static_vote, voxel, window, min_frames, min_share, min_votes, range_ref, top_k: the static
            vote (voxel metres, window ±W frames, range_ref metres or None).
        dissolve_frames, dissolve_confidence, moving_distance, moving_extent, min_static_frames,
            join_gap, join_distance, velocity_frames, class_margin: the track decisions.
        ground_prior, ground_max_confidence, sensor_height: the optional Patchwork++ ground prior
            (``pip install 'dsnet-pipeline[ground]'``).
    """

    static_vote: bool = True
    voxel: float = Field(0.3, gt=0)
    window: int = Field(10, ge=0)
    min_frames: int = Field(3, ge=1)
    min_share: float = Field(0.6, ge=0, le=1)
    min_votes: float = Field(2.0, ge=0)
    range_ref: float | None = Field(20.0, gt=0)
    top_k: int = Field(3, ge=1)
    dissolve_frames: int = Field(3, ge=0)
    dissolve_confidence: float = Field(0.5, ge=0, le=1)
    moving_distance: float = Field(0.5, ge=0)
    moving_extent: float = Field(0.5, ge=0)
    min_static_frames: int = Field(2, ge=0)
    join_gap: int = Field(5, ge=0)
    join_distance: float = Field(1.0, ge=0)
    velocity_frames: int = Field(5, ge=1)
    class_margin: float = Field(2.0, ge=0)
    ground_prior: bool = False
    ground_max_confidence: float = Field(0.6, ge=0, le=1)
    sensor_height: float = Field(1.73, gt=0)


def refine_params(config: RefineConfig):
    """The core's :class:`~dsnet_core.refine.RefineParams` of a stage config."""
    from dsnet_core.refine import GroundParams, RefineParams, TrackParams, VoteParams

    c = config
    return RefineParams(
        vote=VoteParams(c.static_vote, c.voxel, c.window, c.min_frames, c.min_share, c.min_votes, c.range_ref,
                        c.top_k),
        track=TrackParams(c.dissolve_frames, c.dissolve_confidence, c.moving_distance, c.moving_extent,
                          c.min_static_frames, c.join_gap, c.join_distance, c.velocity_frames,
                          c.class_margin),
        ground=GroundParams(c.ground_prior, c.ground_max_confidence, c.sensor_height),
    )  # fmt: skip


CHANGES = TableSpec(
    "refine_changes",
    pa.schema(
        [
            ("index", pa.int32()),  # frame index (the ingest frame table's)
            ("n_points", pa.int64()),
            ("changed", pa.int64()),  # points whose class or id changed
            ("class_changed", pa.int64()),
            ("id_changed", pa.int64()),
            ("by_track", pa.int64()),  # changed by their track's decision (class, join, dissolving)
            ("by_static", pa.int64()),  # given the static vote's class
            ("by_ground", pa.int64()),  # corrected by the ground prior
            ("tracks_joined", pa.int32()),  # joins whose later track starts in this frame
            ("tracks_dissolved", pa.int32()),  # dissolved tracks with points in this frame
            ("from_class", pa.list_(pa.int32())),  # class transitions (train ids) ...
            ("to_class", pa.list_(pa.int32())),
            ("transitions", pa.list_(pa.int64())),  # ... and their point counts
        ]
    ),
    roles=(("item", "index"),),
)

TRACKS = TableSpec(
    "refine_tracks",
    pa.schema(
        [
            ("id", pa.int32()),  # sequence-wide id after joins (the earliest id of a chain)
            ("generation", pa.int32()),  # which hand-out of the id (the temporal stage's; 0 unless reused)
            ("class_id", pa.int32()),  # train id its points take (-1: they keep their own) ...
            ("kept_classes", pa.list_(pa.int32())),  # ... but points of these keep theirs in some frames
            ("first_frame", pa.int32()),
            ("last_frame", pa.int32()),
            ("n_frames", pa.int32()),
            ("n_points", pa.int64()),
            ("moving", pa.bool_()),  # moving, or seen too briefly to tell
            ("joined", pa.list_(pa.int32())),  # the temporal stage's ids it was made of ...
            ("joined_generation", pa.list_(pa.int32())),  # ... and their generations
            ("confidence", pa.float64()),
        ]
    ),
    roles=(("id", "id"), ("generation", "generation"), ("class_id", "class_id"), ("points", "n_points"),
           ("item", "first_frame"), ("confidence", "confidence")),
)  # fmt: skip


class FrameLoader:
    """Reads one frame of a sequence as :class:`~dsnet_core.refine.FrameInput`: the labels of stage
    ``labels``, and the class probabilities of stage ``probs`` per frame through the mapping stage
    ``align`` (:class:`tasks.frames.FrameValues`), when both are given."""

    def __init__(self, ctx: StageContext, labels: str, probs: str | None, align: str | None) -> None:
        from dsnet_core.refine.frame import decode_labels
        from tasks.frames import FrameValues

        self.ctx, self.decode, self.label_map = ctx, decode_labels, ctx.label_map
        self.labels = ctx.arrays(labels)
        self.generations = track_generations(ctx.store, ctx.sequence, ctx.pipeline[labels])
        self.refs = ctx.reader.frames(ctx.sequence)
        t = ctx.frames.to_pydict()
        self.pose = dict(zip(t["index"], t["pose"], strict=True))
        self.time = dict(zip(t["index"], t["timestamp"], strict=True))
        self.probs = self.values = None
        if probs is not None and align is not None:
            ctx._declared(align)
            self.probs = ctx.arrays(probs)
            self.values = FrameValues(ctx.store, ctx.pipeline, ctx.sequence, align)

    def __call__(self, index: int):
        from dsnet_core.refine import FrameInput

        label = self.labels.read_item(index, ["label"])["label"]
        scan = self.ctx.reader.scan(self.refs[index])
        if scan.shape[0] != label.shape[0]:
            raise StoreError(
                self.labels.where,
                f"frame {index}: {label.shape[0]} labels but the log's scan {self.refs[index].scan_path} has "
                f"{scan.shape[0]} points; the log changed since ingest: rerun from ingest",
            )
        sem, inst = self.decode(label, self.label_map)
        pose = self.pose.get(index)
        time = self.time.get(index)
        return FrameInput(
            index=index,
            time=0.1 * index if time is None else float(time),
            pose=None if pose is None else np.asarray(pose, np.float64).reshape(4, 4),
            xyz=np.ascontiguousarray(scan[:, :3], np.float32),
            sem=sem,
            inst=self.generations.keys(inst, index),
            probs=self._probs(index, label.shape[0]),
            intensity=np.ascontiguousarray(scan[:, 3], np.float32) if scan.shape[1] > 3 else None,
        )

    def _probs(self, index: int, n: int) -> np.ndarray | None:
        """uint8 ``(n, C)`` probabilities of the frame's points (read-only), or None."""
        if self.probs is None:
            return None
        found = self.values.frame(self.probs, index, ["probs"])
        if found is None:
            return None
        probs = found["probs"]
        if probs.shape[0] != n:
            raise StoreError(
                self.probs.where, f"frame {index}: {probs.shape[0]} probabilities for {n} labels"
            )
        probs.flags.writeable = False
        return probs


def probability_sources(pipeline, name: str) -> tuple[str | None, str | None]:
    """(the nearest volume stage upstream of ``name`` declaring :data:`PROBS`, the nearest one
    declaring :data:`SOURCE`), or (None, None) unless both exist."""
    from tasks.frames import nearest

    probs = nearest(pipeline, name, (PROBS,), "volume")
    align = nearest(pipeline, name, SOURCE, "volume")
    return (probs, align) if probs is not None and align is not None else (None, None)


class RefineStage(Stage):
    """Refines the final labels of the temporal stage named ``labels``."""

    name = "refine"
    version = "3"  # 2: track keys of reused ids, refine_tracks' generation; 3: class_margin, kept_classes
    Config = RefineConfig
    item = "frame"
    arrays = (FRAME_LABEL,)
    tables = (CHANGES, TRACKS)

    def __init__(self, labels: str = "stitch") -> None:
        self.upstream = (labels, "ingest")

    @property
    def labels(self) -> str:
        return self.upstream[0]

    def inputs(self, ctx: StageContext) -> str:
        """The ground segmenter's version, when the ground prior is on."""
        if not ctx.config.ground_prior:
            return ""
        from importlib.metadata import PackageNotFoundError, version

        try:
            return f"pypatchworkpp:{version('pypatchworkpp')}"
        except PackageNotFoundError:
            return "pypatchworkpp:missing"

    def reads(self, pipeline) -> dict[str, tuple[str, ...]]:
        """The class probabilities and the volume-to-frame mapping of :func:`probability_sources`."""
        probs, align = probability_sources(pipeline, self.name)
        if probs is None:
            return {}
        return {probs: ("probs",), align: tuple(a.name for a in SOURCE)}

    def plan(self, ctx: StageContext) -> Plan:
        from dsnet_core.refine import ClassSets, plan_refinement

        if FRAME_LABEL not in ctx.pipeline[self.labels].arrays or ctx.pipeline[self.labels].item != "frame":
            raise StoreError(
                ctx.store.where(ctx.sequence, self.name), f"{self.labels} declares no per-frame label"
            )
        if ctx.config.ground_prior:
            self._segmenter(ctx)  # a missing extra fails before any block runs
        t = ctx.frames.to_pydict()
        done = ctx.arrays(self.labels).done()
        frames = [int(i) for i, s in zip(t["index"], t["status"], strict=True) if s == "ok" and done[int(i)]]
        probs, align = probability_sources(ctx.pipeline, self.name)
        load = FrameLoader(ctx, self.labels, probs, align)
        plan = plan_refinement(
            (load(f) for f in frames),
            ClassSets.from_label_map(ctx.label_map),
            refine_params(ctx.config),
            self._confidence(ctx),
        )
        d = plan.decisions
        sizes = dict(zip(t["index"], t["n_points"], strict=True))
        return Plan(
            n_items=len(t["index"]),
            max_points=max((int(sizes[f]) for f in frames), default=0),
            meta={
                "refine": plan.to_dict(),
                "probs": probs,
                "align": align,
                "tracks": int(d.ids.size),
                "joins": len(d.joins),
                "joins_refused": d.refused,
                "dissolved": int(d.dissolved.sum()),
                "static_tracks": int((d.static & ~d.dissolved).sum()),
            },
        )

    def _confidence(self, ctx: StageContext) -> dict[int, float] | None:
        """``{track key: confidence}`` from the labels stage's tables that declare both roles (mean per
        id, or per (id, generation) where the table declares a ``generation``)."""
        from dsnet_core.temporal.ids import track_key

        for spec in ctx.pipeline[self.labels].tables:
            id_col, conf_col, gen_col = spec.role("id"), spec.role("confidence"), spec.role("generation")
            if id_col is None or conf_col is None:
                continue
            t = ctx.table(self.labels, spec.name)
            ids = np.asarray(t[id_col].to_numpy(zero_copy_only=False), np.int64)
            if gen_col is not None:
                ids = track_key(ids, np.asarray(t[gen_col].to_numpy(zero_copy_only=False), np.int64))
            conf = np.asarray(t[conf_col].to_numpy(zero_copy_only=False), np.float64)
            ok = np.isfinite(conf)
            uniq, inv = np.unique(ids[ok], return_inverse=True)
            mean = np.bincount(inv, weights=conf[ok]) / np.maximum(np.bincount(inv), 1)
            return {int(i): float(np.clip(c, 0.0, 1.0)) for i, c in zip(uniq, mean, strict=True)}
        return None

    @staticmethod
    def _segmenter(ctx: StageContext):
        from dsnet_core.refine import Patchwork

        return Patchwork(sensor_height=ctx.config.sensor_height)

    def run_block(self, ctx: StageContext, items: list[int]) -> Iterator[ItemResult]:
        from dsnet_core.refine import ClassSets, RefinePlan, encode_labels, refine_block, track_rows

        plan = RefinePlan.from_dict(ctx.plan["refine"])
        known = set(plan.frames)
        targets = [i for i in items if i in known]
        if not targets:
            return
        label_map = ctx.label_map
        load = FrameLoader(ctx, self.labels, ctx.plan["probs"], ctx.plan["align"])
        ground = self._segmenter(ctx) if ctx.config.ground_prior else None
        sets = ClassSets.from_label_map(label_map)
        for r in refine_block(load, targets, plan, sets, refine_params(ctx.config), ground):
            c = r.change
            rows = {"refine_changes": [c.row()]}
            if r.index == plan.frames[0]:
                rows["refine_tracks"] = track_rows(plan.decisions)
            yield ItemResult(
                r.index,
                arrays={"label": encode_labels(r.sem, r.inst, label_map)},
                n_points=c.n_points,
                rows=rows,
                counts={"frames": 1, "points": c.n_points, "changed": c.changed, "by_track": c.by_track,
                        "by_static": c.by_static, "by_ground": c.by_ground},
            )  # fmt: skip
