"""A damaged run store is never read back as complete: a finished DS-Net run (sequence 00 of the
synth log, the seeded tiny checkpoint, fast clusterer) whose files are deleted or truncated is
reported by ``dsnet status`` and ``dsnet export`` (one ``error:`` line naming the file, exit 2,
no traceback), and a rerun recomputes exactly what was lost: the labels and scores are those of
the undamaged run."""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from flows.cli import app
from storage.errors import DamagedStoreError
from storage.run import RunStore
from tasks.methods import get_pipeline
from tests.helpers.label_request import req
from tests.model_helpers import make_checkpoint

P = get_pipeline(refine=False)  # the DS-Net stages
ALL = ("ingest", "align", "infer", "shift", "fuse", "stitch", "score")
FAST_SHIFT = {"kind": "dynamic_shift", "n_seeds": 300, "bandwidths": [0.2, 1.8, 3.4]}
SEQ = "00"


def _request(log, root, ckpt, from_stage=None):
    stages = {"align": {"scans": 1}, "infer": {"checkpoint": str(ckpt)}, "shift": {"clusterer": FAST_SHIFT}}
    stitched = {"temporal": "stitch", "refine": False}  # the stitch stage's files are what these tests damage
    return req(
        str(log), str(root), [SEQ], stages, {"block_size": 3}, from_stage=from_stage, method_options=stitched
    )


@dataclass(frozen=True)
class Finished:
    root: Path  # the undamaged store
    predictions: Path  # its exported .label files
    ckpt: Path


@pytest.fixture(scope="module")
def finished(prefect_api_url, synth_log, tmp_path_factory) -> Finished:
    """One undamaged run of sequence 00 and its exported labels; tests damage copies of it."""
    from flows.export import export_semantickitti
    from flows.label import label_dataset

    ckpt = make_checkpoint(tmp_path_factory.mktemp("ckpt") / "tiny", seed=0)
    root = tmp_path_factory.mktemp("damage") / "run"
    label_dataset(_request(synth_log, root, ckpt))
    out = tmp_path_factory.mktemp("damage-export")
    export_semantickitti(str(root), out)
    return Finished(root, out / "sequences" / SEQ / "predictions", ckpt)


def _copy(finished: Finished, tmp_path) -> Path:
    root = tmp_path / "run"
    shutil.copytree(finished.root, root)
    return root


def _invoke(*args):
    return CliRunner().invoke(app, [str(a) for a in args])


def _status(root, *options: str) -> tuple[dict[str, str], str]:
    res = _invoke("status", root, *options)
    assert res.exit_code == 0, res.output
    states = {}
    for line in res.stdout.splitlines():
        cells = [c.strip() for c in line.split("│")]
        if len(cells) > 3 and cells[1] == SEQ:
            states[cells[2]] = cells[3]
    return states, res.stdout


def _one_line_error(res, *names: str) -> str:
    """``dsnet`` failed with exit 2 and a single ``error:`` line naming every given name."""
    assert res.exit_code == 2, res.output
    assert "Traceback" not in res.output
    lines = [line for line in res.output.splitlines() if line.strip()]
    errors = [line for line in lines if line.startswith("error: ")]
    assert len(errors) == 1, res.output
    assert "damaged" in errors[0] and all(n in errors[0] for n in names), errors[0]
    return errors[0]


def _rerun(log, root, finished: Finished, from_stage=None) -> dict[str, str]:
    from flows.label import label_dataset

    summary = label_dataset(_request(log, root, finished.ckpt, from_stage))
    return {r["stage"]: r["action"] for r in summary}


def _assert_export_identical(root, reference: Path, tmp_path) -> None:
    out = tmp_path / "export"
    res = _invoke("export", root, "--format", "semantickitti", "--out", out)
    assert res.exit_code == 0, res.output
    written = out / "sequences" / SEQ / "predictions"
    names = sorted(p.name for p in reference.iterdir())
    assert sorted(p.name for p in written.iterdir()) == names and len(names) == 6
    for name in names:
        a = np.fromfile(written / name, np.uint32)
        assert a.any() and np.array_equal(a, np.fromfile(reference / name, np.uint32)), name


def _assert_scores_identical(root, reference_root) -> None:
    spec = P["score"].table("frame_metrics")
    assert RunStore(root).read_table(SEQ, spec).equals(RunStore(reference_root).read_table(SEQ, spec))


def test_deleted_stitch_chunk_is_damaged_then_recomputed(finished, synth_log, tmp_path):
    root = _copy(finished, tmp_path)
    chunk = root / "sequences/00/stitch/arrays.zarr/label/c/1/0"
    chunk.unlink()

    states, out = _status(root)
    assert states["stitch"] == "damaged" and all(states[s] == "done" for s in ALL if s != "stitch")
    assert f"damaged: {chunk}: chunk of item 1 is missing" in out.replace("\n", "")

    _one_line_error(_invoke("export", root, "--out", tmp_path / "bad"), str(chunk), "missing")
    assert not (tmp_path / "bad" / "sequences" / SEQ / "predictions" / "000001.label").exists()

    acts = _rerun(synth_log, root, finished)
    assert acts == {**{s: "skip" for s in ALL[:5]}, "stitch": "repair", "score": "fresh"}
    assert set(_status(root)[0].values()) == {"done"}
    _assert_export_identical(root, finished.predictions, tmp_path)
    _assert_scores_identical(root, finished.root)


def test_deleted_infer_chunks_recompute_infer_before_from_stage_shift(finished, synth_log, tmp_path):
    root = _copy(finished, tmp_path)
    infer = root / "sequences/00/infer/arrays.zarr"
    for item in (0, 3):
        for name in ("sem", "probs", "offsets", "features"):
            shutil.rmtree(infer / name / "c" / str(item))
    with pytest.raises(DamagedStoreError, match=r"infer/arrays.zarr/sem/c/0/0: chunk of item 0 is missing"):
        RunStore(root).arrays(SEQ, P["infer"].contract).read_item(0)
    assert _status(root)[0]["infer"] == "damaged"

    acts = _rerun(synth_log, root, finished, from_stage="shift")
    assert acts == {"ingest": "skip", "align": "skip", "infer": "repair", **{s: "fresh" for s in ALL[3:]}}
    arrays = RunStore(root).arrays(SEQ, P["infer"].contract)
    ref = RunStore(finished.root).arrays(SEQ, P["infer"].contract)
    for item in range(arrays.n_items):
        a, b = arrays.read_item(item), ref.read_item(item)
        assert all(np.array_equal(a[k], b[k]) for k in b), item
    _assert_scores_identical(root, finished.root)  # the same PQ, not a lower one
    _assert_export_identical(root, finished.predictions, tmp_path)


def test_a_lost_item_record_is_damage_then_recomputed(finished, synth_log, tmp_path):
    """Store format 1 writes an item's record before its done flag: a done item without one is
    damage (status and status --verify report it, export refuses it), never read as done; a rerun
    recomputes that item and the labels are the undamaged run's."""
    root = _copy(finished, tmp_path)
    record = root / "sequences/00/stitch/items/000002.json"
    record.unlink()

    for options in ((), ("--verify",)):
        states, out = _status(root, *options)
        assert states["stitch"] == "damaged" and all(states[s] == "done" for s in ALL if s != "stitch")
        assert f"damaged: {record}: record of item 2 is missing" in out.replace("\n", "")
    with pytest.raises(DamagedStoreError, match="item 2 is done but its record is missing"):
        RunStore(root).arrays(SEQ, P["stitch"].contract).read_item(2)
    _one_line_error(_invoke("export", root, "--out", tmp_path / "bad"), "item 2", "record")

    acts = _rerun(synth_log, root, finished)
    assert acts == {**{s: "skip" for s in ALL[:5]}, "stitch": "repair", "score": "fresh"}
    assert record.is_file() and set(_status(root, "--verify")[0].values()) == {"done"}
    _assert_export_identical(root, finished.predictions, tmp_path)
    _assert_scores_identical(root, finished.root)


def test_truncated_chunk_is_a_typed_error_then_recomputed(finished, synth_log, tmp_path):
    root = _copy(finished, tmp_path)
    chunk = root / "sequences/00/stitch/arrays.zarr/label/c/2/0"
    chunk.write_bytes(chunk.read_bytes()[: chunk.stat().st_size // 2])

    assert _status(root)[0]["stitch"] == "damaged"
    states, out = _status(root, "--verify")
    assert states["stitch"] == "damaged" and f"damaged: {chunk}" in out.replace("\n", "")
    _one_line_error(_invoke("export", root, "--out", tmp_path / "bad"), str(chunk), "bytes")
    with pytest.raises(DamagedStoreError, match="cannot be decoded"):
        RunStore(root).arrays(SEQ, P["stitch"].contract).read_item(2)

    acts = _rerun(synth_log, root, finished)
    assert acts["stitch"] == "repair" and acts["score"] == "fresh"
    _assert_export_identical(root, finished.predictions, tmp_path)


def test_truncated_frames_partition_is_not_done_then_rewritten(finished, synth_log, tmp_path):
    root = _copy(finished, tmp_path)
    part = root / "tables/frames/sequence=00/part-0.parquet"
    part.write_bytes(part.read_bytes()[:-100])

    states, out = _status(root)
    assert states["ingest"] == "damaged" and str(part) in out.replace("\n", "")
    _one_line_error(_invoke("export", root, "--out", tmp_path / "bad"), str(part), "parquet")

    acts = _rerun(synth_log, root, finished)  # the partition is rewritten from ingest's block fragments
    assert acts == {"ingest": "repair", **{s: "skip" for s in ALL[1:]}}
    spec = P["ingest"].table("frames")
    assert RunStore(root).read_table(SEQ, spec).equals(RunStore(finished.root).read_table(SEQ, spec))
    _assert_export_identical(root, finished.predictions, tmp_path)


def _flip(path: Path, at: int) -> None:
    data = bytearray(path.read_bytes())
    data[at] ^= 0x10
    path.write_bytes(bytes(data))


@pytest.mark.parametrize("what", ["chunk", "parquet"])
def test_a_bit_flip_export_finds_is_repaired_by_the_rerun(what, finished, synth_log, tmp_path):
    """Issue 40: a bit-flipped chunk or parquet partition (same size): `export` said "rerun `dsnet
    label`", `dsnet label` said "nothing to do" (its cheap check sees sizes), and export refused
    again; only --from-stage got out. Now export notes what it found in the store, and the rerun
    checks that stage in full and repairs it."""
    root = _copy(finished, tmp_path)
    if what == "chunk":
        damaged = root / "sequences/00/stitch/arrays.zarr/label/c/2/0"
        stage = "stitch"
    else:
        damaged = root / "tables/frames/sequence=00/part-0.parquet"
        stage = "ingest"
    _flip(damaged, 64 if what == "parquet" else damaged.stat().st_size // 2)  # parquet: a data page
    assert _status(root)[0][stage] == "done"  # same size: the cheap check cannot see it
    _one_line_error(_invoke("export", root, "--out", tmp_path / "bad"), str(damaged))
    assert (root / "sequences/00/damage.json").is_file()

    acts = _rerun(synth_log, root, finished)
    assert acts[stage] == "repair", acts
    assert not (root / "sequences/00/damage.json").exists()
    _assert_export_identical(root, finished.predictions, tmp_path)
