"""Bad options and settings accepted silently or refused late (#27): each is now one line naming the
option (or file) before any server starts or anything is written."""

from __future__ import annotations

import json
import shutil

import pytest
from typer.testing import CliRunner

from dsnet_core.model.card import card_text
from flows.cli import app
from tests.logs import make_log


@pytest.fixture(scope="module")
def log(tmp_path_factory):
    return make_log(tmp_path_factory.mktemp("log"), ("00", "01"), n_frames=3, n_ground=300)


def _refused(args: list[str]) -> str:
    """The one ``error:`` line of a refused command (exit 2, no traceback, nothing else printed)."""
    res = CliRunner().invoke(app, args, env={"COLUMNS": "250"})
    assert res.exit_code == 2, (res.output, res.exception)
    lines = res.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), res.output
    return lines[0].removeprefix("error: ")


TRAIN_REFUSED = [  # (method, extra arguments, the error line)
    ("dsnet", ["--batch-size", "0"], "--batch-size 0: Input should be greater than or equal to 1"),
    ("dsnet", ["--threads", "0"], "--threads 0: Input should be greater than or equal to 1"),
    ("dsnet", ["--lr", "-1"], "--lr -1.0: Input should be greater than 0"),
    ("dsnet", ["--device", "bogus"], "--device 'bogus': expected cpu, cuda or cuda:N"),
    ("dsnet", ["--scans", "0"], "--scans 0: Input should be greater than or equal to 1"),
    ("dsnet", ["--grid", "0,0,0"], "--grid wants three cell counts ≥ 1 'ρ,φ,z', got '0,0,0'"),
    (
        "dsnet",
        ["--grid", "100000,100000,1000"],
        "grid 100000×100000×1000 has 1e+13 cells, more than the "
        "2.15e+09 (2^31) a grid may have (the paper's 480×360×32 has 5.5e+06)",
    ),
    (
        "dsnet",
        ["--epochs", "0"],
        "--epochs '0': 0 epochs for every stage (semantic, offset, joint, shift) "
        "would write an untrained checkpoint; give N ≥ 1",
    ),
    (
        "dsnet",
        ["--stage", "joint", "--epochs", "3"],
        "--stage joint with --epochs '3' trains 0 epochs: name it (e.g. --epochs joint=2)",
    ),
    (
        "most",
        ["--epochs", "detect=0"],
        "--epochs 'detect=0': 0 epochs for every stage (detect, member) would "
        "write an untrained checkpoint; give N ≥ 1",
    ),
    (
        "dpls",
        ["--epochs", "0"],
        "--epochs '0': 0 epochs for every stage (dpls) would write an untrained checkpoint; give N ≥ 1",
    ),
]


@pytest.mark.parametrize(
    ("method", "extra", "want"), TRAIN_REFUSED, ids=[" ".join(c[1]) for c in TRAIN_REFUSED]
)
def test_train_refuses_bad_options_before_anything_is_written(log, tmp_path, method, extra, want):
    out = tmp_path / "ckpt"
    assert _refused(["train", method, str(log), "--out", str(out), *extra]) == want
    assert not out.exists()  # was: an untrained checkpoint for --epochs 0, a ZeroDivisionError, ...


@pytest.mark.parametrize(
    ("extra", "want"),
    [
        (["--device", "bogus"], "--device 'bogus': expected cpu, cuda or cuda:N"),
        (
            ["--clusterer", "bogus"],
            "--clusterer 'bogus': not a kind it takes (expected: 'dynamic_shift', "
            "'meanshift', 'dbscan', 'hdbscan', 'bfs')",
        ),
        (
            ["--clusterer", '{"kind": "dbscan", "eps": -1}'],
            "--clusterer: dbscan.eps -1: Input should be greater than 0",
        ),
        (["--clusterer", '{"eps": 1}'], "--clusterer: a JSON config needs a 'kind' field"),
    ],
    ids=["device", "clusterer", "clusterer-json", "clusterer-no-kind"],
)
def test_label_refuses_bad_stage_settings_before_any_server_starts(log, tmp_path, extra, want):
    """Was: ``--clusterer bogus`` ran ingest, align and infer, then printed a pydantic dump that never
    named the option; ``--device bogus`` ran ingest and align first."""
    run = tmp_path / "run"
    assert _refused(["label", str(log), "--run", str(run), *extra]) == want
    assert not run.exists()


def _card_copy(src, dst, change) -> str:
    shutil.copytree(src, dst)
    card = json.loads((dst / "card.json").read_text())
    change(card["architecture"])
    (dst / "card.json").write_text(card_text(card))
    return str(dst / "card.json")


def test_a_card_grid_beyond_the_bound_is_refused_naming_the_card(log, tmp_path):
    """Was: a card whose grid has 1e12 cells labelled (every point a cell of its own)."""
    from dsnet_core.checkpoints import MOST, bundled_checkpoint

    def huge(arch):
        arch["grid"]["size"] = [10000, 10000, 10000]

    card = _card_copy(bundled_checkpoint(1), tmp_path / "ckpt", huge)
    run = str(tmp_path / "run")
    line = _refused(["label", str(log), "--run", run, "--checkpoint", str(tmp_path / "ckpt"), "--scans", "1"])
    assert line == (
        f"{card}: model card architecture is malformed: grid 10000×10000×10000 has 1e+12 cells, more than "
        "the 2.15e+09 (2^31) a grid may have (the paper's 480×360×32 has 5.5e+06)"
    )

    def fine_bev(arch):
        arch["bev"]["cell"] = 1e-4

    card = _card_copy(MOST.bundled(3), tmp_path / "most", fine_bev)
    line = _refused(["label", str(log), "--run", str(tmp_path / "run"), "--method", "most", "--checkpoint",
                     str(tmp_path / "most")])  # fmt: skip
    assert line.startswith(
        f"{card}: model card architecture is malformed: BEV grid of 1000000² = 1e+12 cells"
    )
    assert line.endswith("is more than the 1.68e+07 (4096²) its dense maps may take")
    assert not (tmp_path / "run").exists()


@pytest.fixture
def labelled(synth_log, tmp_path):
    from tests.tasks.oracle_stitch import score_runs

    (uri,) = score_runs(tmp_path, synth_log, {"run": 0.05}, sequences=("00",), block_size=6, bev=1)
    return uri


def test_export_of_a_sequence_the_run_does_not_have_says_so(labelled, tmp_path):
    """Was: "stage 'oracle' is not done" for a sequence the run never had."""
    line = _refused(["export", labelled, "--out", str(tmp_path / "out"), "--sequences", "00,99"])
    assert line == f"{labelled}: the run has no sequence '99' (it has 00)"


def test_an_export_over_an_older_one_removes_its_stray_labels_and_says_so(labelled, tmp_path):
    out = tmp_path / "out"
    preds = out / "sequences" / "00" / "predictions"
    preds.mkdir(parents=True)
    for name in ("000099.label", "000100.label"):  # an older export's frames this run does not have
        (preds / name).write_bytes(b"\0" * 8)
    (preds / "notes.txt").write_text("kept")  # only .label files are an export's
    res = CliRunner().invoke(app, ["export", labelled, "--out", str(out)], env={"COLUMNS": "250"})
    assert res.exit_code == 0, res.output
    assert (
        "sequence 00: 6 label files; removed 2 .label files an earlier export left for frames this export "
        "does not write: 000099.label, 000100.label"
    ) in res.output
    assert sorted(p.name for p in preds.iterdir()) == [f"{i:06d}.label" for i in range(6)] + ["notes.txt"]
    res = CliRunner().invoke(app, ["export", labelled, "--out", str(out)], env={"COLUMNS": "250"})
    assert "sequence 00: 6 label files\n" in res.output  # nothing stale the second time
