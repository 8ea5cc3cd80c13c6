"""Golden labels: a fixed synthetic log labelled with a small seeded checkpoint made here.

The digests below were recorded before the stage interface was redesigned (stages declaring
their own arrays) and must not change with refactoring. A change that alters labels on purpose
(a new stage version, a generator change) may re-record them, in a commit that says why.

What is hashed: every exported ``.label`` file of the run (k = 1 and k = 2), in frame order, and
the decoded pixels of the report's bird's-eye-view pictures (their PNG bytes may change with the
encoder; the pixels may not).
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest

from tests.model_helpers import make_checkpoint

# recorded at 962284f (before the redesign)
GOLDEN = {
    1: {
        "labels": "f51e39aebabef805fe23bd6e10305145839ec205091294f9bd8d767e77098484",
        "pixels": "09835c19ad3c45df0255b63dd42b0e0aa70c0b90f8e576d5aecfc1d232a1fb4a",
    },
    2: {
        "labels": "554586835150c81e51b9c317cd45b85bfbab234239922a7640c2f5b23408f7e3",
        "pixels": "e8691ae44c8d514f60cd0df8d4424cda69381959b09b1673dda28dc74a0eaff1",
    },
}
# recorded when refine (on by default) was added: the same runs, then refine; exact by construction
# (integer votes of uint8 probabilities), so they hold on any CPU
GOLDEN_REFINED = {
    1: "a3ac995a82d6b02630e06c3e9b7d41bba2cf1bea1b3d82695b19cc14bb741d75",
    2: "79792c527b08552bb5dbb9607c52da58c3be1a62be0c7eb8dd66399c16ef1149",
}
STAGES = ("ingest", "align", "infer", "shift", "fuse", "stitch", "score")
FAST_SHIFT = {"kind": "dynamic_shift", "n_seeds": 400, "bandwidths": [0.2, 1.8, 3.4]}


@pytest.fixture(scope="module")
def golden_log(tmp_path_factory) -> Path:
    from dsnet_core.synth import generate_log

    root = tmp_path_factory.mktemp("golden_log")
    generate_log(root, sequences=1, frames=5, seed=11, sensor="vlp32")
    return root


@pytest.fixture(scope="module")
def golden_ckpt(tmp_path_factory) -> Path:
    return make_checkpoint(tmp_path_factory.mktemp("golden_ckpt") / "ckpt", seed=3)


def _label_run(log: Path, ckpt: Path, root: Path, scans: int, refine: bool = False):
    from flows.export import export_semantickitti
    from flows.report import write_report
    from storage.run import RunStore
    from tasks.methods import get_pipeline
    from tests.helpers.plain_runner import run_stage_plain

    store = RunStore(root / "run")
    run = {
        "data": str(log),
        "stages": {
            "align": {"scans": scans},
            "infer": {"checkpoint": str(ckpt)},
            "shift": {"clusterer": FAST_SHIFT},
        },
        "options": {"block_size": 2},
    }
    pipeline = get_pipeline("dsnet", temporal="stitch", refine=refine)
    stages = [*STAGES[:-1], "refine", "score"] if refine else list(STAGES)
    assert pipeline.names() == stages
    run |= pipeline.record()
    store.write_run_config("golden", run)
    for stage in stages:
        run_stage_plain(store, pipeline, "00", stage, run, "golden")
    write_report(store, pipeline, bev_frames=3, review_rows=5)
    export_semantickitti(str(root / "run"), root / "pred")
    return store


def _digests(store, pred: Path, instances_at_least: int = 10) -> dict[str, str]:
    from dsnet_core.viz.png import decode_png
    from flows.report import read_report_table

    h = hashlib.sha256()
    files = sorted((pred / "sequences" / "00" / "predictions").glob("*.label"))
    assert len(files) == 5
    classes, instances = set(), set()
    for f in files:
        h.update(f.name.encode())
        h.update(f.read_bytes())
        lab = np.fromfile(f, np.uint32)
        classes |= set(np.unique(lab & 0xFFFF).tolist())
        instances |= set(np.unique(lab >> 16).tolist())
    # the digest covers the instance path: several classes and many stitched instances
    assert len(classes) >= 5 and len(instances) >= instances_at_least
    px = hashlib.sha256()
    bev = read_report_table(store, "score_bev").to_pylist()
    assert len(bev) == 3
    for row in sorted(bev, key=lambda r: r["rank"]):
        for key in ("png_pred", "png_gt"):
            img = np.ascontiguousarray(decode_png(row[key]))
            px.update(repr(img.shape).encode())
            px.update(img.tobytes())
    return {"labels": h.hexdigest(), "pixels": px.hexdigest()}


@pytest.mark.parametrize("scans", [1, 2])
def test_golden_labels_and_pictures(golden_log, golden_ckpt, tmp_path, scans):
    store = _label_run(golden_log, golden_ckpt, tmp_path, scans)
    got = _digests(store, tmp_path / "pred")
    assert got == GOLDEN[scans]


@pytest.mark.parametrize("scans", [1, 2])
def test_golden_refined_labels(golden_log, golden_ckpt, tmp_path, scans):
    store = _label_run(golden_log, golden_ckpt, tmp_path, scans, refine=True)
    # the random-weight model's instances are short, unsure fragments: refine dissolves most
    got = _digests(store, tmp_path / "pred", instances_at_least=1)
    assert got["labels"] == GOLDEN_REFINED[scans]
