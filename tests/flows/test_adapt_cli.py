"""``dsnet adapt``: refusals in one line; a SIGKILLed run resumes to the weights of an uninterrupted
one; adapting a tiny unlabelled log and relabelling it with ``dsnet label --checkpoint`` recomputes
infer onward only."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from flows.cli import app
from storage.run import RunStore
from tests.flows.conftest import REPO, cli
from tests.helpers.tiny_log import write_tiny_log
from tests.model_helpers import make_checkpoint

FAST_SHIFT = json.dumps({"kind": "dynamic_shift", "n_seeds": 300, "bandwidths": [0.2, 1.8, 3.4]})


def unlabelled(log: Path) -> Path:
    """``log`` without its label files (what a team's fresh logs look like)."""
    shutil.rmtree(log / "sequences" / "00" / "labels")
    return log


def corrections(log: Path, out: Path, frames: list[str]) -> Path:
    """A labels-only correction folder for ``frames`` of ``log`` (its ground truth as the corrections)."""
    (out / "sequences/00/labels").mkdir(parents=True)
    for f in frames:
        shutil.copyfile(log / f"sequences/00/labels/{f}.label", out / f"sequences/00/labels/{f}.label")
    return out


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--method", "most"], "method most cannot be adapted"),
        (["--labels", "NOPE"], "no corrected frames"),
        (["--steps", "1", "--epochs", "2"], "steps ≥ epochs"),
        (["--keep", "0"], "--keep 0.0: Input should be greater than 0"),
        (["--mix", "cutmix"], "--mix 'cutmix'"),
        (["--from", "NOPE"], "no model card"),
    ],
)
def test_bad_settings_are_refused_in_one_line(tmp_path, extra, message):
    log = write_tiny_log(tmp_path / "log", frames=2, n=500)
    args = [str(tmp_path / a) if a == "NOPE" else a for a in extra]
    res = CliRunner().invoke(app, ["adapt", str(log), "--out", str(tmp_path / "out"), *args])
    assert res.exit_code == 2, res.output
    assert message in res.output and res.output.count("\n") <= 2


def _committed(ckpt: Path) -> int:
    for card in (ckpt / ".pending" / "card.json", ckpt / "card.json"):
        if card.is_file() and (card.parent == ckpt or (ckpt / ".pending" / "COMMIT").is_file()):
            try:
                return sum(json.loads(card.read_text())["epochs"].values())
            except (json.JSONDecodeError, KeyError):
                return 0
    return 0


@pytest.mark.slow
@pytest.mark.timeout(1500)
def test_a_killed_adapt_resumes_to_the_uninterrupted_weights(tmp_path):
    """Random-weight parent, so the corrected frames carry the training; round 2 is labelled by the
    first round's teacher. SIGKILL after the first committed epoch, resume, same bytes."""
    labelled = write_tiny_log(tmp_path / "labelled", frames=4, n=1500)
    fixes = corrections(labelled, tmp_path / "fixes", ["000001", "000003"])
    target = unlabelled(write_tiny_log(tmp_path / "target", frames=4, n=1500))
    source = write_tiny_log(tmp_path / "source", frames=3, n=1500, seed=1)
    parent = make_checkpoint(tmp_path / "parent", seed=3)
    common = [
        str(target),
        "--from",
        str(parent),
        "--labels",
        str(fixes),
        "--source-log",
        str(source),
        "--rounds",
        "2",
        "--steps",
        "4",
        "--epochs",
        "2",
        "--clusterer",
        FAST_SHIFT,
        "--lr",
        "0.01",
    ]
    env = {**os.environ, "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1"}
    straight = tmp_path / "straight"
    done = subprocess.run(
        cli("adapt", *common, "--out", str(straight)),
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    assert "wrote adapted checkpoint" in done.stdout and "relabel: dsnet label" in done.stdout
    card = json.loads((straight / "card.json").read_text())
    assert card["epochs"] == {"round1": 2, "round2": 2}
    adapt = card["training_data"]["adapt"]
    assert adapt["corrected"] == {"path": str(fixes), "train": 2, "held_back": 0}
    assert "2 held-back frames" not in adapt["stopping"] and "fixed budget" in adapt["stopping"]
    assert [r["round"] for r in adapt["rounds"]] == [1, 2] and len(adapt["logs"][0]["fingerprint"]) == 64

    killed = tmp_path / "killed"
    proc = subprocess.Popen(
        cli("adapt", *common, "--out", str(killed)),
        cwd=REPO,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    deadline = time.monotonic() + 600
    while _committed(killed) < 1 and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.01)
    assert proc.poll() is None, f"the run ended before the kill: {proc.stderr.read().decode()[-2000:]}"
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert 1 <= _committed(killed) < 4
    again = subprocess.run(
        cli("adapt", *common, "--out", str(killed)),
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert again.returncode == 2 and "pass --resume" in again.stderr
    resumed = subprocess.run(
        cli("adapt", *common, "--out", str(killed), "--resume"),
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    for name in ("model.safetensors", "student.safetensors"):
        assert (killed / name).read_bytes() == (straight / name).read_bytes(), name


LABEL_STAGES = ("ingest", "align", "infer", "shift", "fuse", "track", "refine")


@pytest.mark.slow
@pytest.mark.timeout(1800)
def test_adapt_a_tiny_unlabelled_log_then_relabel_infer_onward(tmp_path, cli_env):
    """The bundled model labels a tiny unlabelled synthetic log; ``dsnet adapt`` self-trains it
    (pseudo-labels only: no label file anywhere near the target); ``dsnet label --checkpoint`` with
    the adapted model recomputes infer onward and keeps ingest and align."""
    from dsnet_core.synth import generate_log

    target = tmp_path / "target"
    generate_log(target, sequences=1, frames=4, seed=11, sensor="vlp32", style="junction")
    unlabelled(target)
    source = tmp_path / "source"
    generate_log(source, sequences=1, frames=2, seed=12, sensor="vlp16", style="residential")
    run = tmp_path / "run"
    label = ["label", str(target), "--run", str(run), "--scans", "1", "--refine"]
    first = subprocess.run(cli(*label), cwd=REPO, env=cli_env, capture_output=True, text=True, timeout=900)
    assert first.returncode == 0, first.stderr[-3000:]
    store = RunStore(run)
    before = {s: store.read_manifest("00", s) for s in LABEL_STAGES}

    out = tmp_path / "adapted"
    args = [
        "adapt",
        str(target),
        "--out",
        str(out),
        "--rounds",
        "2",
        "--steps",
        "4",
        "--epochs",
        "1",
        "--source-log",
        str(source),
    ]
    res = subprocess.run(cli(*args), cwd=REPO, env=cli_env, capture_output=True, text=True, timeout=1200)
    assert res.returncode == 0, res.stderr[-3000:]
    for step in (
        "round 1 infer",
        "round 1 refine",
        "round 1 select pseudo-labels",
        "round1 epoch 1",
        "round 2 infer",
        "round2 epoch 1",
    ):
        assert step in res.stderr  # progress like train's
    card = json.loads((out / "card.json").read_text())
    rounds = card["training_data"]["adapt"]["rounds"]
    assert rounds[0]["teacher"].endswith("tiny-v2") and rounds[1]["teacher"] == str(out / "rounds/2/teacher")
    assert all(0.05 < r["coverage"] < 1 for r in rounds) and "precision" not in rounds[0]  # no ground truth
    assert "agreement_with_previous_round" in rounds[1]
    assert set(rounds[0]["thresholds"]) <= set(rounds[0]["refined_points_per_class"])
    assert np.isfinite(card["metrics"][-1]["val_source_miou"])
    adapted = [m for m in (out / "rounds/1/pseudo/0/sequences/00/labels").glob("*.label")]
    assert adapted and not (target / "sequences/00/labels").exists()

    again = subprocess.run(
        cli(*label, "--checkpoint", str(out)),
        cwd=REPO,
        env=cli_env,
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert again.returncode == 0, again.stderr[-3000:]
    after = {s: store.read_manifest("00", s) for s in LABEL_STAGES}
    for s in ("ingest", "align"):  # kept: the same manifest, not rewritten
        assert after[s].fingerprint == before[s].fingerprint and after[s].finished == before[s].finished
    for s in LABEL_STAGES[2:]:  # the new model: infer onward recomputed
        assert after[s].fingerprint != before[s].fingerprint and after[s].status == "done", s
    assert after["infer"].config["checkpoint"] == str(out)


def test_like_and_sensor_card_refusals_are_one_line(tmp_path):
    log = write_tiny_log(tmp_path / "log", frames=2, n=500)
    bad = tmp_path / "bad.yaml"
    bad.write_text("card: 1\nbeams: 0\n")
    base = ["adapt", str(log), "--out", str(tmp_path / "out")]
    for extra, message in (
        (["--sensor-card", str(bad)], "bad.yaml: beams: Input should be greater than or equal to 1, got 0"),
        (["--sensor-card", str(tmp_path / "none.yaml")], "cannot read the sensor card"),
        (["--like", str(log), "--sensor-card", str(bad)], "--like and --sensor-card both name"),
        (["--like", str(log), "--source-log", str(log)], "--like renders the synthetic source stream"),
    ):
        res = CliRunner().invoke(app, [*base, *extra])
        assert res.exit_code == 2, res.output
        assert message in res.output and res.output.count("\n") <= 2, res.output
        assert not (tmp_path / "out" / "card.json").exists()


@pytest.mark.slow
@pytest.mark.timeout(900)
def test_adapt_renders_its_source_stream_like_a_log_and_a_resume_keeps_it(tmp_path):
    """A tiny adaptation whose synthetic source stream is rendered with a sensor card: the card is
    recorded in the adapted checkpoint (and the stream's record); resuming with another --like, or
    with the card edited, is refused in one line."""
    from dsnet_core.io.formats import open_log
    from dsnet_core.sensor import estimate_sensor
    from dsnet_core.synth import generate_log

    sensor_log = tmp_path / "sensor_log"
    generate_log(sensor_log, sequences=1, frames=2, seed=5, sensor="vlp16")
    card = estimate_sensor(open_log(sensor_log), sensor_log, name="team-vlp16").card
    card_path = card.save(tmp_path / "team.yaml")
    labelled = write_tiny_log(tmp_path / "labelled", frames=2, n=1500)
    fixes = corrections(labelled, tmp_path / "fixes", ["000000", "000001"])
    target = unlabelled(write_tiny_log(tmp_path / "target", frames=2, n=1500))
    parent = make_checkpoint(tmp_path / "parent", seed=3)  # random weights: the corrections train
    out = tmp_path / "adapted"
    common = [
        str(target), "--out", str(out), "--from", str(parent), "--labels", str(fixes), "--rounds", "1",
        "--steps", "2", "--epochs", "1", "--clusterer", FAST_SHIFT, "--stream-workers", "0",
    ]  # fmt: skip
    env = {**os.environ, "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1"}
    done = subprocess.run(
        cli("adapt", *common, "--sensor-card", str(card_path)),
        cwd=REPO, env=env, capture_output=True, text=True, timeout=800,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    data = json.loads((out / "card.json").read_text())["training_data"]
    recorded = data["adapt"]["source_sensor"]
    assert recorded["option"] == "--sensor-card" and recorded["path"] == str(card_path.resolve())
    assert recorded["card"] == card.model_dump(mode="json")
    assert data["source"]["stream"]["sensor_card"]["name"] == "team-vlp16"

    other = subprocess.run(
        cli("adapt", *common, "--like", str(sensor_log), "--resume"),
        cwd=REPO, env=env, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert other.returncode == 2
    assert f"the source stream's LiDAR: --sensor-card {card_path.resolve()} → --like" in other.stderr
    card.model_copy(update={"mount_height_m": 2.5}).save(card_path)
    edited = subprocess.run(
        cli("adapt", *common, "--sensor-card", str(card_path), "--resume"),
        cwd=REPO, env=env, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert edited.returncode == 2 and "its sensor changed since the adaptation started" in edited.stderr
    assert other.stderr.strip().count("\n") == 0 and edited.stderr.strip().count("\n") == 0
