"""Method ``most`` in the pipeline: the real stages with a random-weight MOST checkpoint (wiring,
table/array consistency, shared stages not recomputed by a method switch), an oracle stand-in for
the network through the real post-processing and the ``track`` stage (PQ^Th and LSTQ ≥ 0.9), and
the errors of settings that do not belong to MOST."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest

from dsnet_core.errors import CheckpointError, ConfigError
from dsnet_core.labels import load_label_map
from storage.run import RunStore
from tasks.base import ItemResult, Plan, StageContext
from tasks.methods import get_pipeline
from tasks.most import MostStage
from tasks.pipeline import Pipeline
from tests.helpers.kill import kill_track_in_a_copy
from tests.helpers.plain_runner import prepare_stage, run_stage_plain
from tests.helpers.run_stages import run_all_stages
from tests.helpers.stand_ins import align_shaped_plan
from tests.model_helpers import make_checkpoint, make_most_checkpoint

LM = load_label_map("semantic-kitti")


@pytest.fixture(scope="module")
def most_run(synth_log, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("most")
    ckpt = make_most_checkpoint(tmp / "most-ckpt", cars=True)
    store = RunStore(tmp / "run")
    run = {
        "data": str(synth_log),
        "method": "most",
        "stages": {"align": {"scans": 1}, "most": {"checkpoint": str(ckpt), "scans": 2}},
        "options": {"block_size": 4},
    }
    return store, run, run_all_stages(store, get_pipeline("most", refine=False), run)


def test_most_labels_every_frame_and_its_tables_agree_with_its_arrays(most_run, synth_log):
    from dsnet_core.io.semantickitti import SemanticKittiReader

    store, _run, m = most_run
    p = get_pipeline("most", refine=False)
    assert [s.name for s in p] == ["ingest", "align", "most", "track", "score"]
    assert m["most"].status == m["track"].status == m["score"].status == "done"
    reader = SemanticKittiReader(synth_log)
    arrays = store.arrays("00", p["most"].contract)
    det = store.read_table("00", p["most"].table("detections")).to_pydict()
    thing = LM.is_thing()
    assert det["index"], "a random network still fires detections"
    for ref in reader.frames("00"):
        out = arrays.read_item(ref.index)
        sem, inst = out["sem"].astype(np.int64), out["inst"]
        assert sem.shape == (reader.scan(ref).shape[0],) and 1 <= sem.min() and sem.max() < LM.num_classes
        rows = [i for i, v in enumerate(det["index"]) if v == ref.index]
        assert [det["id"][i] for i in rows] == list(range(1, len(rows) + 1))
        counts = np.bincount(inst, minlength=len(rows) + 1)
        assert [det["n_points"][i] for i in rows] == counts[1:].tolist()
        for i in rows:  # an instance's points carry its detection's (thing) class
            assert thing[det["class_id"][i]] and set(sem[inst == det["id"][i]].tolist()) <= {
                det["class_id"][i]
            }
        label = store.arrays("00", p["track"].contract).read_item(ref.index)["label"]
        assert label.shape == sem.shape
        assert np.array_equal(LM.to_train(label & 0xFFFF), sem)  # align kept every point in scan order


def test_switching_method_keeps_ingest_and_align(most_run):
    store, run, _m = most_run
    dsnet = get_pipeline("dsnet", temporal="track", refine=False)
    other = {**run, "method": "dsnet", "stages": {"align": {"scans": 1}}}
    for stage in ("ingest", "align"):
        assert prepare_stage(store, dsnet, "00", stage, other, "r2").action == "skip"


def test_most_refuses_a_dsnet_checkpoint_and_multi_scan_volumes(most_run, tmp_path):
    store, run, _ = most_run
    p = get_pipeline("most", refine=False)
    dsnet_ckpt = make_checkpoint(tmp_path / "ds")
    bad = {**run, "stages": {"align": {"scans": 1}, "most": {"checkpoint": str(dsnet_ckpt)}}}
    with pytest.raises(CheckpointError, match="DS-Net checkpoint: label with --method dsnet"):
        prepare_stage(store, p, "00", "most", bad, "r3", force=True)
    wide = {**run, "stages": {**run["stages"], "align": {"scans": 2}}}
    copy = RunStore(tmp_path / "run2")
    copy.write_run_config("r4", wide)
    for stage in ("ingest", "align"):
        run_stage_plain(copy, p, "00", stage, wide, "r4")
    with pytest.raises(ConfigError, match="align must run with scans 1"):
        prepare_stage(copy, p, "00", "most", wide, "r4")


def test_settings_that_are_not_most_s_are_refused():
    from flows.request import LabelRequest
    from tasks.methods import stage_configs

    stages = stage_configs("most", scans=4, checkpoint="/x", device="cpu")
    assert stages == {"align": {"scans": 1}, "most": {"scans": 4, "checkpoint": "/x", "device": "cpu"}}
    for kw, flag in [
        ({"tta": 2}, "--tta"),
        ({"clusterer": "dbscan"}, "--clusterer"),
        ({"stride": 2}, "--stride"),
    ]:
        with pytest.raises(ValueError, match=f"{flag}: not a setting of method most"):
            stage_configs("most", scans=3, **kw)
    req = LabelRequest(data="d", root="r", method="most", method_options={"temporal": "auto"}, stages=stages)
    assert req.pipeline().labels == "refine" and "track" in req.pipeline()  # tracked, then refined
    with pytest.raises(ValueError, match="tracking only"):
        LabelRequest(data="d", root="r", method="most", method_options={"temporal": "stitch"}).pipeline()


class OracleMost(MostStage):
    """Stands in for the network: ground-truth semantics and MOST targets (modal centres, MAX
    extents, velocities) as detections, through the real RoI / distance-membership inference."""

    version = "oracle-1"

    def inputs(self, ctx: StageContext) -> str:
        return ""

    def plan(self, ctx: StageContext) -> Plan:
        return align_shaped_plan(ctx)

    def run_block(self, ctx: StageContext, items: list[int]) -> Iterator[ItemResult]:
        from dsnet_core.most.data import SequenceTargets
        from dsnet_core.most.predict import InferenceSettings, panoptic
        from dsnet_core.oracle.most import oracle_detections

        reader = ctx.reader
        targets = SequenceTargets(reader, [ctx.sequence], LM, min_points=1)
        refs = {f.index: f for f in reader.frames(ctx.sequence)}
        align = ctx.arrays("align")
        for v in items:
            vol = align.read_item(v, ["points", "source_frame", "labels"])
            ref = refs[int(vol["source_frame"][0])]
            sem = LM.to_train(vol["labels"] & 0xFFFF).astype(np.int64)
            det = oracle_detections(targets.targets[(ctx.sequence, ref.frame_id)])
            pred = panoptic(
                vol["points"][:, :3].astype(np.float64), sem, det, InferenceSettings(rule="distance")
            )
            d = pred.detections
            counts = np.bincount(pred.instance, minlength=len(d) + 1)
            rows = [
                {
                    "index": v,
                    "id": i + 1,
                    "class_id": int(d.classes[i]),
                    "n_points": int(counts[i + 1]),
                    "confidence": 1.0,
                    "centre": d.centres[i].tolist(),
                    "extent": d.extents[i].tolist(),
                    "velocity": d.velocity[i].tolist(),
                }
                for i in range(len(d))
            ]
            n = int(sem.size)
            arrays = {"sem": sem.astype(np.uint8), "inst": pred.instance.astype(np.int32)}
            yield ItemResult(v, arrays=arrays, n_points=n, rows={"detections": rows}, counts={"points": n})


def oracle_pipeline() -> Pipeline:
    from tasks.align import AlignStage
    from tasks.ingest import IngestStage
    from tasks.track import TrackStage

    stages = (IngestStage(), AlignStage(), OracleMost(), TrackStage(source="most"))
    return Pipeline("oracle-most", stages, labels="track")


@pytest.fixture(scope="module")
def oracle_run(synth_log, tmp_path_factory):
    store = RunStore(tmp_path_factory.mktemp("oracle") / "run")
    run = {"data": str(synth_log), "stages": {"align": {"scans": 1}}, "options": {}}
    return store, run_all_stages(store, oracle_pipeline(), run)


def test_oracle_detections_through_the_track_stage_recover_the_truth(oracle_run, synth_log):
    from dsnet_core.io.semantickitti import SemanticKittiReader
    from dsnet_core.metrics.evaluator import PanopticEvaluator

    store, m = oracle_run
    assert m["track"].status == "done"
    reader = SemanticKittiReader(synth_log)
    ev = PanopticEvaluator(LM, mode="corrected")  # classes absent from the 6 frames not counted as 0
    labels = store.arrays("00", oracle_pipeline()["track"].contract)
    for ref in reader.frames("00"):
        ev.add(reader.labels(ref), labels.read_item(ref.index)["label"], frame=ref.frame_id, sequence="00")
    res = ev.result()
    # measured (6 VLP-32 frames, seed 0): PQ^Th 1.0000, LSTQ 1.0000
    assert res.panoptic.pq_things >= 0.9 and res.lstq.lstq >= 0.9, (res.panoptic.pq_things, res.lstq.lstq)


def test_track_of_most_killed_mid_sequence_resumes_to_identical_labels(oracle_run, tmp_path):
    store, m = oracle_run
    p = oracle_pipeline()
    reference = [store.arrays("00", p["track"].contract).read_item(f)["label"] for f in range(6)]
    copy = kill_track_in_a_copy(store, "tests.tasks.test_most_stage:oracle_pipeline", tmp_path / "run")
    run = copy.read_run_config("r1")
    assert prepare_stage(copy, p, "00", "track", run, "r1").action == "resume"
    resumed = run_stage_plain(copy, p, "00", "track", run, "r1")
    assert resumed.fingerprint == m["track"].fingerprint
    for f in range(6):
        assert np.array_equal(copy.arrays("00", p["track"].contract).read_item(f)["label"], reference[f])
