"""The dashboard's findings of issue 40, checked on the generated page: a run still in progress is
named with the stage it is at; a run without ground truth is named in the scored sections it is
left out of; the review queue shows frame numbers and units. Oracle-labelled runs (cheap) and a
DS-Net run of ingest and a half-run align (no model)."""

from __future__ import annotations

import re

import pytest
from typer.testing import CliRunner

from flows.cli import app
from flows.dashboard import build_dashboard
from flows.report.tables import REPORT_TABLES
from storage.locks import LockSet, Owner
from storage.run import RunStore
from tasks.methods import get_pipeline
from tests.helpers.plain_runner import prepare_stage, run_block, run_stage_plain
from tests.tasks.oracle_stitch import score_runs

P = get_pipeline("dsnet")


@pytest.fixture
def in_align(synth_log, tmp_path) -> RunStore:
    """A DS-Net run whose ingest is done and whose align ran its blocks but did not finish."""
    store = RunStore(tmp_path / "run")
    run = {"data": str(synth_log), **P.record(), "sequences": ["00"], "stages": {"align": {"scans": 2}},
           "options": {"block_size": 2}}  # fmt: skip
    store.write_run_config("r1", run)
    run_stage_plain(store, P, "00", "ingest", run, "r1")
    for job in prepare_stage(store, P, "00", "align", run, "r1").jobs:
        run_block(job, store)
    return store


def test_a_dashboard_of_a_run_in_progress_names_the_stage_it_is_at(in_align, tmp_path):
    out = tmp_path / "d.html"
    n = len(in_align.read_manifest("00", "align").blocks)
    res = CliRunner().invoke(app, ["dashboard", in_align.uri, "--out", str(out)], terminal_width=300)
    assert res.exit_code == 0, res.output
    where = f"sequence 00 is at stage align (stopped, {n}/{n} blocks done)"
    assert f"note: {in_align.uri}: the run is in progress: {where}" in res.output
    page = out.read_text()
    assert f"the run is in progress: {where}" in page
    locks = LockSet(in_align.root, Owner("r2"))  # a live `dsnet label` holds the stage's lock
    locks.acquire(in_align.lock_rel("00", "align"))
    try:
        res = CliRunner().invoke(app, ["dashboard", in_align.uri, "--out", str(out)], terminal_width=300)
        assert f"sequence 00 is at stage align (running, {n}/{n} blocks done)" in res.output
    finally:
        locks.release_all()


@pytest.fixture(scope="module")
def two_runs(tmp_path_factory, synth_log):
    """Two oracle runs of the synthetic log; B's score tables removed (a log without ground truth)."""
    root = tmp_path_factory.mktemp("dash2")
    a, b = score_runs(root, synth_log, {"runA": 0.05, "runB": 0.15})
    for name in ("score_run", "score_sequences", "score_classes", "score_bev", "refine_scores"):
        if RunStore(b).has_table(REPORT_TABLES[name]):
            RunStore(b).remove_run_table(REPORT_TABLES[name])
    page = build_dashboard([a, b], root / "dashboard.html").read_text()
    return a, b, page


def _section(page: str, sid: str) -> str:
    m = re.search(rf'<section id="{sid}">(.*?)</section>', page, re.S)
    assert m, sid
    return m.group(1)


def test_a_run_without_ground_truth_is_named_in_the_scored_sections(two_runs):
    _, _, page = two_runs
    for sid in ("s-headline", "s-classes", "s-sequences", "s-frames", "s-worst"):
        body = _section(page, sid)
        assert "B · runB has no ground-truth scores: not in this section" in body, sid
        assert body.count("runB") == 1  # the note only: B has no columns, rows or series here
    assert "not in this section" not in _section(page, "s-labelled")
    assert "runB" in _section(page, "s-labelled")  # labelled: both runs
