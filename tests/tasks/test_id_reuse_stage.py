"""Reused instance ids through the real runner and store.

``stitch`` on a sequence that needs more than the 65 535 ids of a label (a stand-in ``fuse`` cuts
every scan into two-point fragments: ~13 000 instances per frame, ~78 000 in the six frames of the
test log) reuses ids outside its window, warns once, counts the reused ids in its manifest and
writes one ``tracks`` row per hand-out of an id; the report's tracks are those hand-outs.

``refine`` after a stand-in labels stage whose ground-truth ids include one reused id (with its
generation in the stage's table) keeps the two tracks of that id apart and refuses the join that
would stretch the id over the later one, where the same labels without the reuse are joined."""

from __future__ import annotations

import logging
from collections.abc import Iterator

import numpy as np
import pyarrow as pa
import pytest

from dsnet_core.labels import class_map_of, load_label_map
from dsnet_core.temporal.ids import MAX_ID, Generations, track_key
from storage.contract import TableSpec
from storage.run import RunStore
from tasks.align import AlignStage
from tasks.base import CLASS_MAP, FRAME_LABEL, ItemResult, Plan, Stage, StageConfig, StageContext
from tasks.ingest import IngestStage
from tasks.pipeline import Pipeline
from tasks.refine import RefineStage
from tasks.stitch import StitchStage
from tests.helpers.plain_runner import run_stage_plain
from tests.helpers.stand_ins import FuseStandIn

LM = load_label_map("semantic-kitti")
CAR = 1
WINDOW = 1  # stitch's id_reuse_after


class Fragments(FuseStandIn):
    """Stands in for ``fuse``: every point a car, points 2i and 2i + 1 of a volume one instance."""

    version = "fragments-1"

    def run_block(self, ctx: StageContext, items: list[int]) -> Iterator[ItemResult]:
        align = ctx.arrays("align")
        for v in items:
            n = align.read_item(v, ["source_index"])["source_index"].size
            yield ItemResult(
                v,
                arrays={"sem": np.full(n, CAR, np.uint8), "inst": (np.arange(n) // 2 + 1).astype(np.int32)},
                n_points=n,
            )


PIPELINE = Pipeline("fragments", (IngestStage(), AlignStage(), Fragments(), StitchStage()), labels="stitch")


@pytest.fixture(scope="module")
def labelled(synth_log, tmp_path_factory):
    store = RunStore(tmp_path_factory.mktemp("reuse") / "run")
    run = {
        "data": str(synth_log),
        "stages": {"align": {"scans": 1}, "stitch": {"id_reuse_after": WINDOW}},
        "options": {"block_size": 6},
    }
    store.write_run_config("r1", run)
    records = []
    handler = logging.Handler()
    handler.emit = records.append  # type: ignore[method-assign]
    logging.getLogger("tasks.track_ids").addHandler(handler)
    try:
        manifests = {s.name: run_stage_plain(store, PIPELINE, "00", s.name, run, "r1") for s in PIPELINE}
    finally:
        logging.getLogger("tasks.track_ids").removeHandler(handler)
    return store, manifests, [r.getMessage() for r in records]


def _labels(store: RunStore, stage: str) -> list[np.ndarray]:
    arrays = store.arrays("00", PIPELINE[stage].contract)
    return [arrays.read_item(f)["label"] for f in range(arrays.n_items)]


def test_stitch_reuses_ids_outside_its_window_and_says_so(labelled):
    store, m, warnings = labelled
    stitch = m["stitch"]
    assert stitch.status == "done" and stitch.counts["frames"] == 6
    n_tracks = stitch.counts["tracks"]
    assert n_tracks > MAX_ID + 10_000 and stitch.counts["ids_reused"] == n_tracks - MAX_ID
    assert len(warnings) == 1 and "stitch 00: the 65535 instance ids" in warnings[0]
    t = store.read_table("00", PIPELINE["stitch"].table("tracks")).to_pydict()
    ids, gen = np.asarray(t["id"]), np.asarray(t["generation"])
    assert len(ids) == n_tracks and gen.max() == 1
    assert np.unique(track_key(ids, gen)).size == ids.size  # one row per (id, generation)
    assert (np.lexsort((gen, ids)) == np.arange(ids.size)).all()
    first, last = np.asarray(t["first_frame"]), np.asarray(t["last_frame"])
    again = np.flatnonzero(gen == 1)
    before = again - 1  # the id's generation 0: rows are sorted by (id, generation)
    assert (ids[before] == ids[again]).all() and (gen[before] == 0).all()
    assert (first[again] - last[before] > WINDOW).all()
    # every fragment of a frame has its own id, and the table's generations name its track
    gens = Generations(ids, gen, first)
    seen = set()
    for f, label in enumerate(_labels(store, "stitch")):
        inst = (label >> 16).astype(np.int64)
        assert (inst > 0).all() and (label & 0xFFFF == LM.learning_map_inv[CAR]).all()
        pairs = inst.reshape(-1, 2) if inst.size % 2 == 0 else inst[:-1].reshape(-1, 2)
        assert (pairs[:, 0] == pairs[:, 1]).all() and np.unique(pairs[:, 0]).size == pairs.shape[0]
        keys = gens.keys(np.unique(inst), f)  # an odd last point is a fragment of its own
        assert not seen & set(keys.tolist()), "a track (id, generation) in two frames"
        seen |= set(keys.tolist())
    assert seen == set(track_key(ids, gen).tolist())


def test_the_reports_tracks_are_the_hand_outs_of_the_ids(labelled):
    from flows.report.confidence import ConfidencePass
    from flows.report.labelled import summarise

    store, _, _ = labelled
    summary = summarise(store, PIPELINE, ["00"], LM, ConfidencePass())
    rows = summary.tracks
    keys = [track_key(r["id"], r["generation"]) for r in rows]
    t = store.read_table("00", PIPELINE["stitch"].table("tracks")).to_pydict()
    assert sorted(keys) == sorted(track_key(np.asarray(t["id"]), np.asarray(t["generation"])).tolist())
    assert summary.sequences[0]["tracks"] == len(rows) == len(t["id"])
    assert sum(r["n_points"] for r in rows) == sum(t["n_points"])


REUSED = 900  # an id the log's ground truth does not use


class ReusedConfig(StageConfig):
    reuse: bool = True


class ReusedTruth(Stage):
    """Stands in for a temporal stage: ground-truth labels, with the id :data:`REUSED` on object A
    in frames 0-1 (then its own id) and, in frames 3-5, on object B (until then its own id) — a
    second hand-out of the id, generation 1 in the ``truth_tracks`` table (with ``reuse`` off: id
    ``REUSED + 1``, generation 0). A and B: the two objects with the most points in every frame."""

    name = "truth"
    upstream = ("ingest",)
    version = "reused-1"
    Config = ReusedConfig
    item = "frame"
    arrays = (FRAME_LABEL,)
    tables = (
        TableSpec(
            "truth_tracks",
            pa.schema([("id", pa.int32()), ("generation", pa.int32()), ("first_frame", pa.int32())]),
            roles=(("id", "id"), ("generation", "generation"), ("item", "first_frame")),
        ),
    )

    def plan(self, ctx: StageContext) -> Plan:
        reader = ctx.reader
        refs = reader.frames(ctx.sequence)
        points: dict[int, list[int]] = {}
        for ref in refs:
            inst = reader.labels(ref) >> 16
            ids, n = np.unique(inst[inst > 0], return_counts=True)
            for i, c in zip(ids.tolist(), n.tolist(), strict=True):
                points.setdefault(i, []).append(c)
        a, b = sorted((i for i in points if len(points[i]) == len(refs)), key=lambda i: -sum(points[i]))[:2]
        n = ctx.frames["n_points"].to_pylist()
        return Plan(n_items=len(n), max_points=max(n), meta={CLASS_MAP: class_map_of(LM), "a": a, "b": b})

    def run_block(self, ctx: StageContext, items: list[int]) -> Iterator[ItemResult]:
        reader = ctx.reader
        refs = reader.frames(ctx.sequence)
        a, b = ctx.plan["a"], ctx.plan["b"]
        later = (REUSED, 1) if ctx.config.reuse else (REUSED + 1, 0)
        for i in items:
            label = reader.labels(refs[i]).astype(np.uint32)
            inst = label >> 16
            new = inst.copy()
            if i <= 1:
                new[inst == a] = REUSED
            if i >= 3:
                new[inst == b] = later[0]
            label = (label & 0xFFFF) | (new << 16)
            rows = []
            if i == len(refs) - 1:  # one row per track: (id, generation, first frame)
                rows = [{"id": int(t), "generation": 0, "first_frame": 0} for t in np.unique(inst[inst > 0])]
                rows[[r["id"] for r in rows].index(a)]["first_frame"] = 2
                rows += [
                    {"id": REUSED, "generation": 0, "first_frame": 0},
                    {"id": later[0], "generation": later[1], "first_frame": 3},
                ]
            yield ItemResult(
                i, arrays={"label": label}, n_points=int(label.size), rows={"truth_tracks": rows}
            )


def _refined(log, root, reuse: bool):
    pipeline = Pipeline(
        "reused", (IngestStage(), ReusedTruth(), RefineStage(labels="truth")), labels="refine"
    )
    store = RunStore(root)
    run = {"data": str(log), "stages": {"truth": {"reuse": reuse}}, "options": {"block_size": 6}}
    store.write_run_config("r1", run)
    m = {s.name: run_stage_plain(store, pipeline, "00", s.name, run, "r1") for s in pipeline}
    labels = store.arrays("00", pipeline["refine"].contract)
    out = [labels.read_item(f)["label"] for f in range(labels.n_items)]
    return m, out, store.read_table("00", pipeline["refine"].table("refine_tracks")).to_pydict()


def test_refine_keeps_the_tracks_of_a_reused_id_apart(synth_log, tmp_path):
    from dsnet_core.io.semantickitti import SemanticKittiReader

    reader = SemanticKittiReader(synth_log)
    truth = [reader.labels(ref) >> 16 for ref in reader.frames("00")]
    plain_m, plain, _ = _refined(synth_log, tmp_path / "plain", reuse=False)
    a, b = plain_m["truth"].plan["a"], plain_m["truth"].plan["b"]
    # without the reuse, A's two ids are joined (the earlier one, REUSED, wins) and B's too
    assert plain_m["refine"].plan["joins_refused"] == 0
    for f, label in enumerate(plain):
        assert set(np.unique(label[truth[f] == a] >> 16).tolist()) == {REUSED}
        assert set(np.unique(label[truth[f] == b] >> 16).tolist()) == {b}
    m, got, tracks = _refined(synth_log, tmp_path / "reused", reuse=True)
    # with it, stretching REUSED over A's frames 2-5 would meet B's REUSED (generation 1) in 3-5
    assert (
        m["refine"].plan["joins_refused"] == 1
        and m["refine"].plan["joins"] == plain_m["refine"].plan["joins"] - 1
    )
    for f, label in enumerate(got):
        ida, idb = (np.unique(label[truth[f] == o] >> 16).tolist() for o in (a, b))
        assert ida == ([REUSED] if f <= 1 else [a]) and idb == [b], (f, ida, idb)
    keys = track_key(np.asarray(tracks["id"]), np.asarray(tracks["generation"]))
    assert np.unique(keys).size == keys.size
    row = tracks["id"].index(REUSED)  # the first hand-out only: frames 0-1 (not 0-5)
    assert (tracks["first_frame"][row], tracks["last_frame"][row], tracks["generation"][row]) == (0, 1, 0)
    joined = dict(
        zip(tracks["id"], zip(tracks["joined"], tracks["joined_generation"], strict=True), strict=True)
    )
    assert joined[b] == ([b, REUSED], [0, 1])  # B took its later REUSED part back


def test_the_tracked_table_has_a_row_per_hand_out_of_an_id():
    from tasks.track import _summarise, _track_rows

    summary: dict = {}
    car = LM.learning_map_inv[CAR]
    # frame 0: tracks 5 and 7; frame 200: id 5 again, its generation 1 (key 5 | 1 << 16)
    _summarise(summary, 0, np.array([car | 5 << 16, car | 7 << 16, car | 7 << 16], np.uint32),
               np.array([5, 7]), np.array([CAR, CAR]))  # fmt: skip
    _summarise(
        summary, 200, np.array([car | 5 << 16] * 4, np.uint32), np.array([track_key(5, 1)]), np.array([CAR])
    )
    rows = _track_rows(summary, LM)
    assert [(r["id"], r["generation"], r["first_frame"], r["n_points"]) for r in rows] == [
        (5, 0, 0, 1),
        (5, 1, 200, 4),
        (7, 0, 0, 2),
    ]
