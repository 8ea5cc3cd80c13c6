"""``dsnet status``: the states of unfinished stages (running, interrupted), a log that gained a scan
(stale), the bytes each stage stores (``--verbose``), and a run folder that is a file. Ingest and
align of the DS-Net method through the plain runner (no model) on a copy of the synthetic log."""

from __future__ import annotations

import os
import shutil

import pytest
from typer.testing import CliRunner

from flows.cli import app
from storage.locks import LockSet, Owner
from storage.run import RunStore
from tasks.methods import get_pipeline
from tests.helpers.plain_runner import prepare_stage, run_block, run_stage_plain

P = get_pipeline("dsnet")


def _run_config(log) -> dict:
    return {"data": str(log), **P.record(), "sequences": ["00"], "stages": {"align": {"scans": 2}},
            "options": {"block_size": 2}}  # fmt: skip


@pytest.fixture
def labelled(synth_log, tmp_path):
    """(store, log): ingest done, align's blocks all run but the stage not finished (a Ctrl-C
    between its last block and its tables)."""
    log = tmp_path / "log"
    shutil.copytree(synth_log, log)
    store = RunStore(tmp_path / "run")
    run = _run_config(log)
    store.write_run_config("r1", run)
    run_stage_plain(store, P, "00", "ingest", run, "r1")
    decision = prepare_stage(store, P, "00", "align", run, "r1")
    for job in decision.jobs:
        run_block(job, store)
    return store, log


def _status(*args) -> tuple[dict[str, list[str]], list[str]]:
    res = CliRunner().invoke(app, ["status", *map(str, args)], terminal_width=200)
    assert res.exit_code == 0, res.output
    rows, notes = {}, []
    for line in res.stdout.splitlines():
        cells = [c.strip() for c in line.split("│")]
        if len(cells) > 3 and cells[1] == "00":
            rows[cells[2]] = cells[3:-1]
        elif line.startswith(("scores (", "no ground truth scored")):
            continue  # the headline (the scores, or that none are): not a note
        elif not line.startswith(("┏", "┃", "┡", "└", "│", " ")) and line.strip():
            notes.append(line)
    assert "no ground truth scored" in res.stdout  # ingest and align only: nothing scored
    return rows, notes


def test_unfinished_stages_say_interrupted_or_running(labelled):
    store, _ = labelled
    rows, notes = _status(store.uri)
    n = len(store.read_manifest("00", "align").blocks)
    assert rows["ingest"][:2] == ["done", "3/3"]  # blocks of 2 frames
    assert rows["align"][:2] == ["interrupted (all blocks done, not finished)", f"{n}/{n}"]
    assert rows["infer"][0] == "missing" and rows["infer"][1] == ""
    assert notes == [
        "unfinished stages: `dsnet label` with the same --run resumes them from their finished blocks"
    ]
    locks = LockSet(store.root, Owner("r2"))  # a live run holds the stage's lock
    locks.acquire(store.lock_rel("00", "align"))
    try:
        assert _status(store.uri)[0]["align"][:2] == ["running", f"{n}/{n}"]
    finally:
        locks.release_all()


def test_a_scan_added_to_the_log_makes_the_run_stale(labelled):
    store, log = labelled
    velodyne = log / "sequences" / "00" / "velodyne"
    assert _status(store.uri)[0]["ingest"][0] == "done"
    shutil.copy(velodyne / "000005.bin", velodyne / "000006.bin")
    rows, notes = _status(store.uri)
    assert rows["ingest"][0] == "stale (log changed)"
    assert rows["align"][0].startswith("interrupted")  # unfinished stays unfinished
    assert "stale: sequence 00: the log has 7 frames, the run 6 (1 new, 0 gone)" in notes[0]
    (velodyne / "000002.bin").unlink()
    (velodyne / "000006.bin").unlink()
    assert "the log has 5 frames, the run 6 (0 new, 1 gone)" in _status(store.uri)[1][0]


def _files(path) -> int:
    return sum(os.path.getsize(os.path.join(d, f)) for d, _, fs in os.walk(path) for f in fs)


def test_verbose_reports_the_bytes_of_each_stage(labelled):
    store, log = labelled
    rows, notes = _status(store.uri, "--verbose")
    root = store.uri
    ingest = _files(f"{root}/sequences/00/ingest") + _files(f"{root}/tables/frames/sequence=00")
    align = _files(f"{root}/sequences/00/align")  # its table is written when it finishes
    assert store.stage_bytes("00", P["ingest"].contract)["tables"] > 0
    assert sum(store.stage_bytes("00", P["ingest"].contract).values()) == ingest
    assert sum(store.stage_bytes("00", P["align"].contract).values()) == align
    assert rows["ingest"][-2:] == [_size(ingest), _size(ingest / 6)]
    assert rows["align"][-2:] == [_size(align), _size(align / 6)]
    scans = _files(log / "sequences" / "00" / "velodyne")
    total = ingest + align
    assert notes[1] == f"store: {_size(total)}, {_size(total / 6)} per frame over 6 frames"
    assert notes[-1] == f"the log's scans: {_size(scans)}; the store is {total / scans:.2f}× that"


def _size(n: float) -> str:
    from flows.status_view import size

    return size(n)


def test_size_units():
    from flows.status_view import size

    assert [size(v) for v in (0, 999, 1000, 4096, 16.3e6, 123e6, 2.05e9)] == [
        "0 B", "999 B", "1 kB", "4.1 kB", "16.3 MB", "123 MB", "2.05 GB",
    ]  # fmt: skip


def test_a_file_is_not_a_run_folder(tmp_path):
    path = tmp_path / "notes.txt"
    path.write_text("hello")
    res = CliRunner().invoke(app, ["status", str(path)])
    assert res.exit_code == 2 and "Traceback" not in res.output
    assert (
        res.output.strip()
        == f"error: {path}: is a file, not a run folder (the folder `dsnet label --run` wrote)"
    )


def _report_states(root) -> dict[str, str]:
    res = CliRunner().invoke(app, ["status", str(root)], terminal_width=200)
    assert res.exit_code == 0, res.output
    cells = [[c.strip() for c in line.split("│")] for line in res.stdout.splitlines()]
    return {c[2]: c[3] for c in cells if len(c) > 3 and c[1] == "(run)"}


def test_refine_tables_of_an_earlier_refined_run_are_marked_after_no_refine(labelled):
    from flows.report.tables import REPORT_TABLES

    store, log = labelled
    store.write_run_table(REPORT_TABLES["refine_transitions"], [])
    store.write_run_table(REPORT_TABLES["stage_timings"], [])
    assert _report_states(store.uri)["table refine_transitions"] == "done"  # refine on (default)
    run = _run_config(log)
    run["method_options"] = {**run["method_options"], "refine": False}
    run["stage_versions"].pop("refine")
    run["labels_stage"] = "stitch"
    store.write_run_config("r2", run)  # the same run folder relabelled with --no-refine
    states = _report_states(store.uri)
    assert states["table refine_transitions"] == "from an earlier run (refine is off)"
    assert states["table stage_timings"] == "done"
