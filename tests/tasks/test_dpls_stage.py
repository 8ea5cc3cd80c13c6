"""Method ``dpls`` in the pipeline: the real stages with a user prior (ground truth written as
prediction files) and a random-weight D-PLS checkpoint (wiring, the prior carried through to the
labels), switching the prior's source keeps ingest and align, the refusals of mismatched priors,
and the oracle: ground-truth prior and noisy ground-truth centres through DBSCAN, fusion and
stitching give PQ^Th and LSTQ ≥ 0.9."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest

from dsnet_core.errors import ConfigError, PriorFormatError
from dsnet_core.labels import class_map_of, load_label_map
from storage.run import RunStore
from tasks.base import CLASS_MAP, ItemResult, Plan, StageContext
from tasks.dpls import DplsStage
from tasks.methods import get_pipeline
from tasks.pipeline import Pipeline
from tests.helpers.plain_runner import prepare_stage, run_stage_plain
from tests.helpers.run_stages import run_all_stages
from tests.model_helpers import make_checkpoint, make_dpls_checkpoint, write_gt_prior

LM = load_label_map("semantic-kitti")


@pytest.fixture(scope="module")
def dpls_run(synth_log, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("dpls")
    prior = write_gt_prior(synth_log, tmp / "prior")
    ckpt = make_dpls_checkpoint(tmp / "dpls-ckpt")
    store = RunStore(tmp / "run")
    run = {
        "data": str(synth_log),
        "method": "dpls",
        "stages": {
            "align": {"scans": 2},
            "prior": {"source": "user", "path": str(prior)},
            "dpls": {"checkpoint": str(ckpt)},
            "shift": {"clusterer": {"kind": "dbscan"}},
        },
        "options": {"block_size": 2},
    }
    return store, run, run_all_stages(store, get_pipeline("dpls", refine=False), run), tmp


def test_dpls_carries_the_prior_to_the_final_labels(dpls_run):
    store, _run, m, _tmp = dpls_run
    p = get_pipeline("dpls", refine=False)
    assert p.names() == ["ingest", "align", "prior", "dpls", "shift", "fuse", "stitch", "score"]
    assert all(m[s].status == "done" for s in p.names())
    align = store.arrays("00", p["align"].contract)
    prior = store.arrays("00", p["prior"].contract)
    dpls = store.arrays("00", p["dpls"].contract)
    fuse = store.arrays("00", p["fuse"].contract)
    thing = LM.is_thing()
    for v in range(align.n_items):
        gt = LM.to_train(align.read_item(v, ["labels"])["labels"] & 0xFFFF)
        pri = prior.read_item(v)
        out = dpls.read_item(v)
        assert np.array_equal(pri["sem"], gt) and np.array_equal(out["sem"], gt)
        assert np.array_equal(out["probs"], pri["prior"]) and out["probs"].shape[1] == LM.num_classes
        assert np.array_equal(pri["prior"].argmax(1), gt) and set(np.unique(pri["prior"])) <= {0, 255}
        assert out["offsets"].dtype == np.float32 and out["features"].shape[1] == 32
        stuff = ~thing[gt]  # shift reads offsets and features on thing points only
        assert not out["offsets"][stuff].any() and not out["features"][stuff].any()
        fused = fuse.read_item(v)
        stuff = ~thing[gt]
        assert np.array_equal(fused["sem"][stuff], gt[stuff]) and not fused["inst"][stuff].any()
    assert m["dpls"].plan["checkpoint"].endswith("dpls-ckpt")
    score = store.read_manifest("00", "score")
    assert score.status == "done"


def test_switching_the_prior_source_recomputes_only_prior_and_downstream(dpls_run):
    store, run, _m, tmp = dpls_run
    p = get_pipeline("dpls", refine=False)
    model = make_checkpoint(tmp / "semantic-ckpt")
    other = {**run, "stages": {**run["stages"], "prior": {"source": "model", "checkpoint": str(model)}}}
    for stage in ("ingest", "align"):
        assert prepare_stage(store, p, "00", stage, other, "r2").action == "skip"
    assert prepare_stage(store, p, "00", "prior", other, "r2").action == "fresh"
    store.write_run_config("r2", other)
    run_stage_plain(store, p, "00", "prior", other, "r2")
    assert store.read_manifest("00", "prior").plan["checkpoint"].endswith("semantic-ckpt")
    assert prepare_stage(store, p, "00", "dpls", other, "r2").action == "fresh"
    # and back: the user prior again is a new fingerprint for prior, the old one for align
    assert prepare_stage(store, p, "00", "align", run, "r3").action == "skip"


def test_a_prior_whose_count_or_classes_do_not_match_is_refused(dpls_run, synth_log, tmp_path):
    _store, run, _m, _tmp = dpls_run
    p = get_pipeline("dpls", refine=False)
    prior = write_gt_prior(synth_log, tmp_path / "short", layout="flat")
    f = prior / "00" / "000002.label"
    f.write_bytes(f.read_bytes()[:-8])
    short = {**run, "stages": {**run["stages"], "prior": {"source": "user", "path": str(prior)}}}
    copy = RunStore(tmp_path / "run")
    copy.write_run_config("r4", short)
    for stage in ("ingest", "align"):
        run_stage_plain(copy, p, "00", stage, short, "r4")
    with pytest.raises(
        PriorFormatError, match=r"000002\.label: has \d+ points but its scan .*000002\.bin has"
    ):
        run_stage_plain(copy, p, "00", "prior", short, "r4")
    # probabilities over another label map's classes: the prior stage reads them, dpls refuses
    nus = load_label_map("panoptic-nuscenes")
    probs_dir = tmp_path / "nus"
    (probs_dir / "00").mkdir(parents=True)
    frames = copy.read_table("00", p["ingest"].table("frames")).to_pydict()
    for fid, n in zip(frames["frame_id"], frames["n_points"], strict=True):
        np.save(probs_dir / "00" / f"{fid}.npy", np.eye(nus.num_classes, dtype=np.float32)[np.ones(n, int)])
    nus_prior = {"source": "user", "path": str(probs_dir), "label_map": "panoptic-nuscenes"}
    wrong = {**run, "stages": {**run["stages"], "prior": nus_prior}}
    copy.write_run_config("r5", wrong)
    run_stage_plain(copy, p, "00", "prior", wrong, "r5")
    with pytest.raises(
        ConfigError, match=r"semantic prior's classes .*panoptic-nuscenes.* are not those of D-PLS"
    ):
        prepare_stage(copy, p, "00", "dpls", wrong, "r5")


class OracleDpls(DplsStage):
    """Stands in for the network: ground-truth box centres of each volume's instances with realistic
    regression noise (:func:`dsnet_core.oracle.inputs.noisy_centres`) as offsets; the prior's
    classes as semantics, as the real stage."""

    version = "oracle-1"

    def inputs(self, ctx: StageContext) -> str:
        return ""

    def plan(self, ctx: StageContext) -> Plan:
        align = ctx.manifest("align")
        return Plan(
            n_items=align.n_items,
            max_points=int(align.plan["max_points"]),
            meta={"checkpoint": "oracle", CLASS_MAP: class_map_of(LM)},
            dims={"classes": LM.num_classes, "features": 32},
        )

    def run_block(self, ctx: StageContext, items: list[int]) -> Iterator[ItemResult]:
        from dsnet_core.oracle.inputs import box_centres, noisy_centres

        align, prior = ctx.arrays("align"), ctx.arrays("prior")
        for v in items:
            vol = align.read_item(v, ["points", "labels"])
            xyz = vol["points"][:, :3]
            sem = LM.to_train(vol["labels"] & 0xFFFF).astype(np.int64)
            ids = (vol["labels"] >> 16).astype(np.int64)
            key = np.where(LM.is_thing()[sem] & (ids > 0), (sem << 20) | ids, 0)
            centres = noisy_centres(xyz, box_centres(xyz, key), key, seed=v)
            pri = prior.read_item(v, ["prior", "sem"])
            n = int(sem.size)
            arrays = {
                "sem": pri["sem"],
                "probs": pri["prior"],
                "offsets": (centres - xyz).astype(np.float32),
                "features": np.zeros((n, 32), np.float16),
            }
            yield ItemResult(v, arrays=arrays, n_points=n, counts={"points": n})


def test_oracle_prior_and_centres_through_dbscan_fusion_and_stitching(synth_log, tmp_path):
    from dsnet_core.io.semantickitti import SemanticKittiReader
    from dsnet_core.metrics.evaluator import PanopticEvaluator
    from tasks.align import AlignStage
    from tasks.fuse import FuseStage
    from tasks.ingest import IngestStage
    from tasks.prior import PriorStage
    from tasks.shift import ShiftStage
    from tasks.stitch import StitchStage

    p = Pipeline(
        "oracle-dpls",
        (IngestStage(), AlignStage(), PriorStage(), OracleDpls(), ShiftStage(source="dpls"),
         FuseStage(source="dpls"), StitchStage()),
        labels="stitch",
    )  # fmt: skip
    prior = write_gt_prior(synth_log, tmp_path / "prior")
    run = {
        "data": str(synth_log),
        "stages": {
            "align": {"scans": 2},
            "prior": {"source": "user", "path": str(prior)},
            "shift": {"clusterer": {"kind": "dbscan"}},
        },
        "options": {},
    }
    store = RunStore(tmp_path / "run")
    m = run_all_stages(store, p, run)
    assert m["stitch"].status == "done"
    reader = SemanticKittiReader(synth_log)
    ev = PanopticEvaluator(LM, mode="corrected")
    labels = store.arrays("00", p["stitch"].contract)
    for ref in reader.frames("00"):
        ev.add(reader.labels(ref), labels.read_item(ref.index)["label"], frame=ref.frame_id, sequence="00")
    res = ev.result()
    assert res.panoptic.pq_things >= 0.9 and res.lstq.lstq >= 0.9, (res.panoptic.pq_things, res.lstq.lstq)
