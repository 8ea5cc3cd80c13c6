"""Issue 40's findings on logs and labelling (one test a finding; model folders: test_model_folders.py)."""

from __future__ import annotations

import numpy as np
import pytest

from dsnet_core.errors import ScanFormatError
from dsnet_core.io.folder import FolderReader
from storage.run import RunStore
from tasks.methods import get_pipeline
from tests.helpers.plain_runner import run_stage_plain
from tests.logs import make_log

P = get_pipeline()  # the DS-Net stages


def _folder_log(tmp_path, n_frames: int = 4):
    """A folder log of ``.npy`` scans with KITTI poses, its first scan holding an ``inf`` coordinate."""
    src = make_log(tmp_path / "kitti", ("00",), n_frames=n_frames, n_ground=400, n_car=60)
    folder = tmp_path / "folder"
    folder.mkdir()
    for i in range(n_frames):
        scan = np.fromfile(src / f"sequences/00/velodyne/{i:06d}.bin", np.float32).reshape(-1, 4)
        if i == 0:
            scan[5, 0] = np.inf
        np.save(folder / f"scan{i}.npy", scan)
    (folder / "poses.txt").write_text((src / "sequences/00/poses.txt").read_text())
    return folder


def test_a_bad_first_scan_quarantines_only_its_frame(tmp_path):
    """Finding: with ``--on-error skip`` a first scan with an ``inf`` coordinate quarantined every frame
    (the sequence's intensity convention was decided on that scan alone)."""
    folder = _folder_log(tmp_path)
    reader = FolderReader(folder)
    frames = reader.frames("folder")
    with pytest.raises(ScanFormatError, match=r"scan0\.npy"):
        reader.scan(frames[0])
    assert reader.intensity_convention("folder") == "unit"  # decided on scan1, the first that reads
    assert reader.scan(frames[1]).shape[1] == 4

    store = RunStore(tmp_path / "run")
    run = {"data": str(folder), "format": "folder", "options": {"block_size": 2, "on_error": "skip"}}
    store.write_run_config("r1", run)
    m = run_stage_plain(store, P, "folder", "ingest", run, "r1")
    t = store.read_table("folder", P["ingest"].table("frames")).to_pydict()
    assert t["status"] == ["quarantined", "ok", "ok", "ok"] and m.counts["quarantined"] == 1
    assert "scan0.npy" in t["reason"][0] and t["reason"][1:] == [None, None, None]
    assert all(n > 0 for n in t["n_points"][1:])
    # the run's closing summary says what was skipped (finding: it did not)
    from flows.commands.label_report import quarantined_lines

    lines = quarantined_lines(store, ["folder"])
    assert lines[0] == "  quarantined 1 of 4 frames (--on-error skip; they have no labels):"
    assert lines[1].startswith(f"    folder/scan0: {folder / 'scan0.npy'}") and len(lines) == 2


def test_no_readable_scan_names_the_first_scans_problem(tmp_path):
    folder = _folder_log(tmp_path, n_frames=2)
    scan = np.load(folder / "scan1.npy")
    scan[0, 1] = np.inf
    np.save(folder / "scan1.npy", scan)
    reader = FolderReader(folder)
    with pytest.raises(ScanFormatError, match=r"scan0\.npy"):
        reader.intensity_convention("folder")


def _label(*args) -> tuple[int, str]:
    from typer.testing import CliRunner

    from flows.cli import app

    res = CliRunner().invoke(app, ["label", *map(str, args)])
    return res.exit_code, res.output


def test_label_refuses_a_log_without_poses_at_two_scans_before_any_server(tmp_path):
    """Finding: `dsnet label` on a log without poses at --scans 2 started a Prefect server (8–10 s)
    and printed the error four times. Now one line, before any server or stage, naming the folder."""
    log = make_log(tmp_path / "log", ("00",), n_frames=3, n_ground=300, n_car=40)
    (log / "sequences/00/poses.txt").unlink()
    code, text = _label(log, "--run", tmp_path / "run", "--scans", "2")
    assert code == 2 and text.count("\n") == 1, text
    assert text.startswith(
        f"error: {log.resolve() / 'sequences/00/velodyne'}: sequence 00: volumes of --scans 2"
    )
    assert "--estimate-poses, or label with --scans 1" in text
    assert "Prefect" not in text and not (tmp_path / "run").exists()


def test_label_refuses_a_bad_scan_before_any_server_and_skip_quarantines_it(tmp_path):
    """Finding: a log whose content is bad (here an inf coordinate, as `describe` finds) started a
    server first. With --on-error skip the check leaves the frame to ingest's quarantine."""
    folder = _folder_log(tmp_path)
    code, text = _label(folder, "--run", tmp_path / "run", "--scans", "1")
    assert code == 2 and text.count("\n") == 1, text
    assert f"{folder / 'scan0.npy'}" in text and "Prefect" not in text
    from flows.preflight import check_content
    from flows.request import LabelRequest

    request = LabelRequest(data=str(folder), root=str(tmp_path / "run"), options={"on_error": "skip"})
    check_content(request)  # passes: the bad frame is quarantined by ingest


def test_argmax_over_all_classes_reproduces_the_reference_rule(tmp_path):
    """Also: the product's argmax is over classes 1..19; the reference's ``calc_sem_label`` over all
    20. ``argmax="all"`` (infer setting ``argmax: all``) gives the reference's labels; the default is
    unchanged and is left out of the infer record (existing runs keep their fingerprints)."""
    import torch

    from dsnet_core.model.inference import Predictor
    from tasks.infer import InferConfig
    from tests.helpers.tiny_log import tiny_frame
    from tests.model_helpers import make_checkpoint

    ck = make_checkpoint(tmp_path / "ck", seed=2)
    points, _ = tiny_frame(0, n=3000)
    ours = Predictor.from_checkpoint(ck).predict(points)
    ref = Predictor.from_checkpoint(ck, argmax="all").predict(points)
    assert (ours.sem > 0).all() and np.array_equal(ours.probs, ref.probs)
    differ = ours.sem != ref.sem
    assert differ.any() and (ref.sem[differ] == 0).all()  # only where "unlabelled" wins
    assert np.array_equal(ours.sem[ref.sem > 0], ref.sem[ref.sem > 0])  # elsewhere the same class
    assert "argmax" not in InferConfig().model_dump(mode="json")
    assert InferConfig(argmax="all").model_dump(mode="json")["argmax"] == "all"
    with pytest.raises(ValueError, match="argmax must be one of"):
        Predictor(torch.nn.Module(), argmax="none")


def test_adapt_refuses_a_bad_clusterer_before_the_teacher_runs(tmp_path):
    """Finding: `adapt --clusterer bogus` ran the teacher's ingest, align and infer (9 s) before a raw
    pydantic message."""
    from typer.testing import CliRunner

    from flows.cli import app
    from tests.helpers.tiny_log import write_tiny_log
    from tests.model_helpers import make_checkpoint

    log = write_tiny_log(tmp_path / "log", frames=2, n=500)
    parent = make_checkpoint(tmp_path / "parent")
    out = tmp_path / "ad"
    res = CliRunner().invoke(
        app, ["adapt", str(log), "--out", str(out), "--from", str(parent), "--clusterer", "bogus"]
    )
    lines = [ln for ln in res.output.splitlines() if ln.strip()]  # (an empty progress display's blank line)
    assert res.exit_code == 2 and len(lines) == 1, res.output
    assert lines[0].startswith("error: --clusterer 'bogus': not a kind it takes (expected: 'dynamic_shift'")
    assert not out.exists()  # no teacher store, no folder


def test_from_stage_refine_with_no_refine_names_the_option():
    """Finding: `--from-stage refine --no-refine` said "unknown stage refine"."""
    from tasks.methods import get_method

    pipeline = get_method("dsnet").pipeline({"refine": False}, {})
    with pytest.raises(
        ValueError, match=r"stage 'refine' is off in this run \(--no-refine\): its stages are \["
    ):
        pipeline.check_stage("refine")
    with pytest.raises(ValueError, match="unknown stage 'bogus'"):
        pipeline.check_stage("bogus")


def test_train_most_help_lists_every_preset_it_takes():
    """Finding: `train most --preset reference` ran (silently, for minutes) though --help listed only
    tiny, small and paper."""
    from typer.testing import CliRunner

    from dsnet_core.model.presets import PRESETS
    from flows.cli import app
    from tasks.methods.most import MostTrainOptions

    described = MostTrainOptions.model_fields["preset"].description
    assert all(name in described for name in PRESETS), described
    assert "reference" in CliRunner().invoke(app, ["train", "most", "--help"]).output


def test_a_bad_frame_found_by_ingest_is_printed_once(cli_env, tmp_path):
    """Finding: a content error met in a stage was printed four times (three Prefect ERROR lines,
    then `error:`). A bad middle frame (the preflight reads first and last scans) is now one line."""
    import subprocess

    from tests.flows.conftest import REPO, cli

    folder = _folder_log(tmp_path, n_frames=3)
    scan = np.load(folder / "scan0.npy")
    scan[5, 0] = 1.0  # the first scan reads again; the middle one is bad
    np.save(folder / "scan0.npy", scan)
    bad = np.load(folder / "scan1.npy")
    bad[7, 2] = np.inf
    np.save(folder / "scan1.npy", bad)
    res = subprocess.run(
        cli("label", str(folder), "--run", str(tmp_path / "run"), "--scans", "1"),
        cwd=REPO, env=cli_env, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert res.returncode == 2, res.stderr[-3000:]
    said = [ln for ln in res.stderr.splitlines() if "scan1.npy" in ln]
    assert said == [f"error: {folder / 'scan1.npy'}: 1 points have NaN or inf values (first: point 7)"], (
        res.stderr
    )


def test_serve_prints_one_line_per_tick(prefect_api_url, cli_env, tmp_path):
    """Finding: `serve` printed about ten Prefect INFO lines per tick (51 in 6 ticks). Now one line
    per tick: what it labelled (and, as before, a warning line for what it left out)."""
    import subprocess
    import time

    from prefect.deployments import run_deployment

    from tests.flows.conftest import REPO, cli
    from tests.flows.test_serve import _wait_deployment

    watched = make_log(tmp_path / "watched", ("00", "01"), n_frames=3, n_ground=300)
    env = {k: v for k, v in cli_env.items() if k != "PREFECT_LOGGING_LEVEL"}
    env["PREFECT_RUNNER_POLL_FREQUENCY"] = "1"
    args = ("serve", "--watch", str(watched), "--runs", str(tmp_path / "runs"), "--cron", "0 3 * * *")
    args += ("--name", "quiet", "--scans", "1", "--until", "align", "--check-every", "1")
    log = tmp_path / "serve.log"
    with open(log, "wb") as out:
        proc = subprocess.Popen(cli(*args), cwd=REPO, env=env, stdout=out, stderr=subprocess.STDOUT)
    try:
        _wait_deployment("auto-label/auto-label-quiet", proc)
        for _ in range(2):
            assert run_deployment("auto-label/auto-label-quiet", timeout=300).state.is_completed()
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and log.read_text().count("tick '") < 2:
            time.sleep(0.5)
        text = log.read_text()  # while serving (Prefect's runner warns of its own shutdown)
    finally:
        proc.terminate()
        proc.wait(timeout=30)
    lines = [ln for ln in text.splitlines() if ln.strip()]
    ticks = [ln for ln in lines if ln.startswith("tick '")]
    assert len(ticks) == 2, "\n".join(lines[-40:])
    assert sorted(t.split(": ", 1)[1] for t in ticks) == [
        "labelled 2 sequence(s): 00, 01",
        "labelled nothing: nothing new or stale",
    ]
    assert not [ln for ln in lines if "| INFO" in ln], "\n".join(lines[-40:])
    assert lines[0].startswith("serving auto-label of") and len(lines) == 3, "\n".join(lines)
