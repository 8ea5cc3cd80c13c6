"""Stage infer through the plain runner on a synthetic vlp32 log (k = 2),
with a random-weight tiny checkpoint: values against direct dsnet_core calls, invariants, resume."""

import numpy as np
import pytest

from dsnet_core.labels import load_label_map
from dsnet_core.model.inference import Predictor
from storage.run import RunStore
from tasks.infer import dequantise_probs
from tasks.runner import run_stage_plain
from tests.model_helpers import make_checkpoint

LM = load_label_map("semantic-kitti")
STAGES = ("ingest", "align", "infer")
SHIFT_4D = {"kind": "dynamic_shift", "n_seeds": 300, "bandwidths": [0.2, 1.8, 3.4]}


def run_config(log, ckpt, scans=2, clusterer=None):
    return {
        "data": str(log),
        "stages": {
            "align": {"scans": scans},
            "infer": {"checkpoint": str(ckpt)},
        },
        "options": {"block_size": 2},
    }


@pytest.fixture(scope="module")
def labelled(synth_log, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("stages")
    ckpt = make_checkpoint(tmp / "ckpt", seed=0)
    store = RunStore(tmp / "run")
    run = run_config(synth_log, ckpt)
    store.write_run_config("r1", run)
    manifests = {s: run_stage_plain(store, "00", s, run, "r1") for s in STAGES}
    return store, run, ckpt, manifests


def test_infer_matches_the_predictor(labelled):
    store, _, ckpt, m = labelled
    assert m["infer"].n_items == m["align"].n_items == 5 and m["infer"].status == "done"
    pts = store.arrays("00", "align").read_item(3)["points"]
    got = store.arrays("00", "infer").read_item(3)
    want = Predictor.from_checkpoint(ckpt).predict(pts)
    assert np.array_equal(got["sem"], want.sem) and got["sem"].dtype == np.uint8
    assert np.abs(dequantise_probs(got["probs"]) - want.probs.astype(np.float32)).max() <= 1 / 510 + 1e-3
    assert np.array_equal(got["offsets"], want.offsets) and np.array_equal(got["features"], want.features)
    assert m["infer"].counts["points"] == m["align"].counts["points"]
    assert m["infer"].counts["thing_points"] > 0  # random weights still predict some thing classes
