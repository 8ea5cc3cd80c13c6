"""Stage ``track`` on ground-truth instances whose ids are scrambled in every volume (so only the
tracker can make them sequence-wide): LSTQ near 1 at k = 1 where ``stitch`` can only hand out
fresh ids, labels in the scans' point order, and a kill in the middle resumes to identical labels."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest

from dsnet_core.labels import load_label_map
from storage.run import RunStore
from tasks.align import AlignStage
from tasks.base import ItemResult, StageContext
from tasks.ingest import IngestStage
from tasks.pipeline import Pipeline
from tasks.stitch import StitchStage
from tasks.track import TrackStage
from tests.helpers.kill import kill_track_in_a_copy
from tests.helpers.plain_runner import run_stage_plain
from tests.helpers.stand_ins import FuseStandIn

LM = load_label_map("semantic-kitti")


class ScrambledTruth(FuseStandIn):
    """Stands in for ``fuse``: ground-truth classes and instances, each volume's ids permuted."""

    version = "truth-1"

    def run_block(self, ctx: StageContext, items: list[int]) -> Iterator[ItemResult]:
        align = ctx.arrays("align")
        for v in items:
            labels = align.read_item(v, ["labels"])["labels"]
            sem = LM.to_train(labels & 0xFFFF)
            inst = (labels >> 16).astype(np.int64)
            ids = np.unique(inst[inst > 0])
            perm = np.random.default_rng(v).permutation(ids.size) + 1
            lut = np.zeros(int(inst.max(initial=0)) + 1, np.int64)
            lut[ids] = perm
            yield ItemResult(
                v,
                arrays={"sem": sem.astype(np.uint8), "inst": lut[inst].astype(np.int32)},
                n_points=int(labels.size),
                counts={"points": int(labels.size)},
            )


def pipeline(temporal: str) -> Pipeline:
    last = TrackStage() if temporal == "track" else StitchStage()
    stages = (IngestStage(), AlignStage(), ScrambledTruth(), last)
    return Pipeline(f"truth-{temporal}", stages, labels=temporal)


def track_pipeline() -> Pipeline:
    return pipeline("track")


def _run(store: RunStore, log, temporal: str) -> dict:
    p = pipeline(temporal)
    run = {"data": str(log), "stages": {"align": {"scans": 1}}, "options": {"block_size": 4}}
    store.write_run_config("r1", run)
    return {s.name: run_stage_plain(store, p, "00", s.name, run, "r1") for s in p}


@pytest.fixture(scope="module")
def tracked(synth_log, tmp_path_factory):
    store = RunStore(tmp_path_factory.mktemp("track") / "run")
    return store, _run(store, synth_log, "track")


def test_tracking_makes_scrambled_ids_sequence_wide(tracked, synth_log, tmp_path):
    from dsnet_core.io.semantickitti import SemanticKittiReader

    store, m = tracked
    assert m["track"].status == "done" and m["track"].counts["frames"] == 6
    stitched = RunStore(tmp_path / "stitch")
    _run(stitched, synth_log, "stitch")
    reader = SemanticKittiReader(synth_log)
    labels = store.arrays("00", TrackStage().contract)
    for ref in reader.frames("00"):  # the scan's order, the truth's classes
        got = labels.read_item(ref.index)["label"]
        assert np.array_equal(LM.to_train(got & 0xFFFF), LM.to_train(reader.labels(ref) & 0xFFFF))
    rows = store.read_table("00", TrackStage().table("tracked")).to_pydict()
    assert rows["id"] == sorted(set(rows["id"])) and max(rows["n_frames"]) == 6  # parked cars: every frame
    track, stitch = _lstq(store, reader, "track"), _lstq(stitched, reader, "stitch")
    assert track > 0.95 > stitch, (track, stitch)


def _lstq(store: RunStore, reader, stage: str) -> float:
    from dsnet_core.metrics.evaluator import PanopticEvaluator

    ev = PanopticEvaluator(LM)
    labels = store.arrays("00", pipeline(stage)[stage].contract)
    for ref in reader.frames("00"):
        ev.add(reader.labels(ref), labels.read_item(ref.index)["label"], frame=ref.frame_id, sequence="00")
    return ev.result().lstq.lstq


@pytest.mark.parametrize("keep_state", [True, False])
def test_track_killed_mid_sequence_resumes_to_identical_labels(tracked, tmp_path, keep_state):
    from tests.helpers.plain_runner import prepare_stage

    store, m = tracked
    p = pipeline("track")
    reference = [store.arrays("00", p["track"].contract).read_item(f)["label"] for f in range(6)]
    copy = kill_track_in_a_copy(store, "tests.tasks.test_track_stage:track_pipeline", tmp_path / "run")
    # written after frame 0, then whenever the time since outweighs its cost (base.STATE_SHARE)
    assert copy.root.read_json("sequences/00/track/state.json")["position"] in (0, 1, 2)
    if not keep_state:  # replayed from the first frame instead
        copy.root.remove("sequences/00/track/state.json")
    run = copy.read_run_config("r1")
    assert prepare_stage(copy, p, "00", "track", run, "r1").action == "resume"
    resumed = run_stage_plain(copy, p, "00", "track", run, "r1")
    assert resumed.fingerprint == m["track"].fingerprint and resumed.counts == m["track"].counts
    for f in range(6):
        assert np.array_equal(copy.arrays("00", p["track"].contract).read_item(f)["label"], reference[f])
    assert copy.read_table("00", p["track"].table("tracked")).equals(
        store.read_table("00", p["track"].table("tracked"))
    )
