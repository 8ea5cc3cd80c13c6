"""The score stage on a nuScenes log: a SemanticKITTI model's labels against the log's Panoptic
nuScenes ground truth through the recorded class mapping, in the nuScenes metrics; a model whose
classes have no mapping to the ground truth's is refused, naming the file it looked for."""

from __future__ import annotations

import numpy as np
import pytest

from dsnet_core.errors import ConfigError
from dsnet_core.io.formats import open_log
from dsnet_core.io.semantickitti import SemanticKittiReader
from dsnet_core.labels import class_map_of, load_label_map
from dsnet_core.metrics.scoring import make_scorer
from flows.report import read_report_table, write_report
from storage.run import RunStore
from tasks.base import CLASS_MAP, ItemResult, Plan, StageContext
from tasks.ingest import IngestStage
from tasks.pipeline import Pipeline
from tasks.score import ScoreStage
from tests.dsnet_core.io.encode import quantised_log, write_nuscenes
from tests.helpers.plain_runner import run_stage_plain
from tests.tasks.oracle_stitch import LM, OracleStitch, OracleStitchConfig, perturb

SCENE = "scene-0001"


class SourceOracleConfig(OracleStitchConfig):
    source: str  # the SemanticKITTI log the nuScenes log was re-encoded from
    class_map_name: str = "semantic-kitti"


class SourceOracle(OracleStitch):
    """Perturbed SemanticKITTI ground truth of the source log, frame by frame: a SemanticKITTI
    model's labels of the nuScenes log (same points, same order)."""

    Config = SourceOracleConfig

    def plan(self, ctx: StageContext) -> Plan:
        plan = super().plan(ctx)
        plan.meta[CLASS_MAP] = {**class_map_of(LM), "name": ctx.config.class_map_name}
        return plan

    def run_block(self, ctx: StageContext, items: list[int]):
        src = SemanticKittiReader(ctx.config.source)
        refs = src.frames("00")
        for i in items:
            pred = perturb(src.labels(refs[i]), i, ctx.config.noise, ctx.config.seed)
            yield ItemResult(i, arrays={"label": pred}, n_points=int(pred.size), counts={"frames": 1})


P = Pipeline("nusc-oracle", (IngestStage(), SourceOracle(), ScoreStage(labels="oracle")), labels="oracle")


@pytest.fixture(scope="module")
def logs(synth_log, tmp_path_factory):
    src = quantised_log(synth_log, tmp_path_factory.mktemp("src"), 4, convention="uint8")
    nusc = tmp_path_factory.mktemp("nusc")
    write_nuscenes(SemanticKittiReader(src), nusc)
    return src, nusc


def _run(tmp_path, src, nusc, **oracle):
    store = RunStore(tmp_path / "run")
    run = {
        "data": str(nusc),
        **P.record(),
        "stages": {"oracle": {"source": str(src), **oracle}},
        "options": {"block_size": 3},  # two blocks: the scene's tracking state crosses a block
    }
    store.write_run_config("r1", run)
    return store, run


def test_a_nuscenes_run_is_scored_in_nuscenes_metrics_through_the_mapping(logs, tmp_path):
    src, nusc = logs
    store, run = _run(tmp_path, src, nusc)
    for stage in P.names():
        m = run_stage_plain(store, P, SCENE, stage, run, "r1")
    assert m.status == "done" and m.n_items == 4 and len(m.blocks) == 2
    scoring = m.plan["scoring"]
    assert scoring["metric"] == "panoptic-nuscenes" and scoring["min_points"] == 15
    assert scoring["mapping"]["file"] == "semantic-kitti-to-panoptic-nuscenes.yaml"
    assert scoring["mapping"]["classes"]["other-vehicle"] == "bus"
    write_report(store, P, bev_frames=1, review_rows=0)
    row = read_report_table(store, "score_run").to_pylist()[0]

    one = make_scorer(load_label_map("panoptic-nuscenes"), LM)  # the reference: one pass, in order
    reader, source = open_log(nusc), SemanticKittiReader(src)
    for i, (ref, s) in enumerate(zip(reader.frames(SCENE), source.frames("00"), strict=True)):
        one.add(reader.labels(ref), perturb(source.labels(s), i, 0.05, 0), sequence=SCENE)
    want = one.summary()
    assert row["scoring"] == "panoptic-nuscenes"
    assert row["class_mapping"] == "semantic-kitti-to-panoptic-nuscenes.yaml" and row["min_points"] == 15
    for key in ("pq", "sq", "rq", "miou", "lstq", "pat", "tq", "ptq"):
        assert row[key] == want["all"][key], key
    for key in ("pq", "miou", "lstq", "pat"):
        assert row[f"{key}_expressible"] == want["expressible"][key], key
    assert 0.5 < row["pq_expressible"] <= 1 and row["pat"] > 0
    classes = {r["class"]: r for r in read_report_table(store, "score_classes").to_pylist()}
    assert len(classes) == 16 and not classes["barrier"]["expressible"] and classes["car"]["expressible"]
    frames = store.read_table(SCENE, P["score"].table("frame_metrics")).to_pydict()
    assert frames["frame_id"] == [f.frame_id for f in reader.frames(SCENE)]  # sample_data tokens
    assert len(frames["pq"]) == 4 and np.isfinite(frames["pq"]).all()


def test_a_model_without_a_mapping_to_the_ground_truth_is_refused(logs, tmp_path):
    src, nusc = logs
    store, run = _run(tmp_path, src, nusc, class_map_name="my-classes")
    for stage in ("ingest", "oracle"):
        run_stage_plain(store, P, SCENE, stage, run, "r1")
    with pytest.raises(
        ConfigError, match=r"no class mapping dsnet_core/data/my-classes-to-panoptic-nuscenes"
    ):
        run_stage_plain(store, P, SCENE, "score", run, "r1")
