"""Issue 40's model-folder findings: the output folders of ``train``, ``adapt`` and
``import-checkpoint`` are locked, checked before any work, and resumed only with what they were
made with. In-process (typer's runner): every refusal comes before any training."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from typer.testing import CliRunner

from dsnet_core.errors import CheckpointError, CheckpointImportError
from dsnet_core.model.card import card_text
from dsnet_core.model.checkpoint import load_checkpoint, read_card, save_checkpoint
from flows.cli import app
from flows.commands.model_folder import LOCK, writing_folder
from tests.dsnet_core.model.reference_net import Cylinder3DReference, DSNetReference, randomize, spconv1_state
from tests.helpers.tiny_log import write_tiny_log
from tests.model_helpers import make_checkpoint

TRAIN = ("--stage", "semantic", "--grid", "24,32,8", "--threads", "1")


def invoke(*args) -> tuple[int, str]:
    res = CliRunner().invoke(app, [str(a) for a in args])
    return res.exit_code, res.output


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    root = tmp_path_factory.mktemp("logs")
    return write_tiny_log(root / "a", frames=2), write_tiny_log(root / "b", frames=2, seed=1)


@pytest.fixture(scope="module")
def trained(logs, tmp_path_factory):
    """A finished one-epoch semantic training (lr 0.001, seed 0, augmented) on log ``a``."""
    out = tmp_path_factory.mktemp("trained") / "ck"
    code, text = invoke("train", "dsnet", logs[0], "--out", out, "--epochs", "semantic=1", *TRAIN)
    assert code == 0, text
    return out


@pytest.fixture
def ck(trained, tmp_path):
    """A copy of the trained folder to resume or damage."""
    return Path(shutil.copytree(trained, tmp_path / "ck"))


@pytest.fixture(scope="module")
def reference_files(tmp_path_factory):
    root = tmp_path_factory.mktemp("ref")
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    dsnet = root / "dsnet.pth"
    torch.save({"epoch": 1, "model_state": spconv1_state(randomize(DSNetReference(4)).state_dict())}, dsnet)
    cyl = root / "cylinder.pth"
    torch.save({"model_state": spconv1_state(randomize(Cylinder3DReference(4)).state_dict())}, cyl)
    torch.set_num_threads(before)
    return dsnet, cyl


# -- locks ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("command", ["train", "adapt", "import"])
def test_a_second_writer_of_a_folder_gets_one_line(command, logs, reference_files, tmp_path):
    """Finding: two trainings (or adaptations) into one folder at once both wrote; only the second
    survived. Now the first holds the folder's lock (owner + heartbeat) and the second stops at once."""
    out = tmp_path / "busy"
    args = {
        "train": ("train", "dsnet", logs[0], "--out", out, "--epochs", "semantic=1", *TRAIN),
        "adapt": ("adapt", logs[1], "--out", out, "--from", tmp_path / "nowhere"),
        "import": ("import-checkpoint", reference_files[0], "--out", out, "--kind", "dsnet"),
    }[command]
    with writing_folder(out, "dsnet train dsnet"):
        holder = json.loads((out / LOCK).read_text())
        assert holder["pid"] == os.getpid() and holder["run_id"].startswith("dsnet train dsnet ")
        code, text = invoke(*args)
        assert code == 2 and text.count("\n") == 1, text
        assert f"{out}: being written by `dsnet train dsnet` (pid {os.getpid()} on host" in text
        assert "wait for it to finish or stop it, or choose another --out" in text
    assert not (out / LOCK).exists() and not out.exists()  # released; the empty folder removed


def test_a_killed_writers_lock_is_taken_over(reference_files, tmp_path):
    """A SIGKILLed training leaves its lock: a dead pid on this host is stale, so the next writer
    (a --resume) takes the folder over."""
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    out = tmp_path / "ck"
    out.mkdir()
    record = {"host": os.uname().nodename, "pid": dead.pid, "run_id": "dsnet train dsnet 0", "acquired": 0}
    (out / LOCK).write_text(json.dumps({**record, "heartbeat": 1e18}))
    code, text = invoke("import-checkpoint", reference_files[0], "--out", out, "--kind", "dsnet")
    assert code == 0, text
    assert not (out / LOCK).exists() and read_card(out).training_data["imported"]["kind"] == "dsnet"


# -- --out a file or under a file ------------------------------------------------------------------
@pytest.mark.parametrize("where", ["file", "under"])
@pytest.mark.parametrize("command", ["dsnet", "most", "dpls", "import", "adapt"])
def test_an_out_that_is_a_file_is_refused_before_any_work(command, where, logs, reference_files, tmp_path):
    """Finding: train dsnet|most lost a full epoch before a traceback, dpls and import-checkpoint
    gave tracebacks, adapt said "the store is damaged"."""
    afile = tmp_path / "afile"
    afile.write_text("x")
    out = afile if where == "file" else afile / "ck"
    args = {
        "dsnet": ("train", "dsnet", logs[0], "--out", out, "--epochs", "semantic=1", *TRAIN),
        "most": ("train", "most", logs[0], "--out", out, "--epochs", "detect=1"),
        "dpls": ("train", "dpls", logs[0], "--out", out, "--epochs", "1"),
        "import": ("import-checkpoint", reference_files[0], "--out", out, "--kind", "dsnet"),
        "adapt": ("adapt", logs[1], "--out", out),
    }[command]
    code, text = invoke(*args)
    assert code == 2 and text.count("\n") == 1, text
    assert text.startswith(f"error: {afile}: is a file"), text
    assert "damaged" not in text and afile.read_text() == "x"


# -- resume consistency ----------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("change", "named"),
    [
        (("--lr", "0.002"), "--lr: 0.001 → 0.002"),
        (("--seed", "4"), "--seed: 0 → 4"),
        (("--no-augment",), "--no-augment: True → False"),
        (("--batch-size", "2"), "--batch-size: 1 → 2"),
    ],
)
@pytest.mark.parametrize("epochs", ["semantic=1", "semantic=3"], ids=["finished", "partial"])
def test_a_resume_with_changed_settings_is_refused_naming_them(change, named, epochs, logs, ck):
    """Finding: a changed --lr, --seed or --no-augment was accepted on a resume (the card then
    claimed them for epochs trained without them), or silently ignored on a finished checkpoint."""
    card = (ck / "card.json").read_bytes()
    code, text = invoke(
        "train", "dsnet", logs[0], "--out", ck, "--epochs", epochs, *TRAIN, *change, "--resume"
    )
    assert code == 2 and text.count("\n") == 1, text
    assert f"{ck} was trained with other settings: {named}." in text
    assert (ck / "card.json").read_bytes() == card


def test_a_resume_on_another_data_log_is_refused(logs, ck):
    code, text = invoke("train", "dsnet", logs[1], "--out", ck, "--epochs", "semantic=1", *TRAIN, "--resume")
    assert code == 2 and f"DATA: {logs[0].resolve()} → {logs[1].resolve()}" in text, text


def test_a_resume_with_the_same_settings_continues(logs, ck):
    code, text = invoke("train", "dsnet", logs[0], "--out", ck, "--epochs", "semantic=1", *TRAIN, "--resume")
    assert code == 0 and "wrote checkpoint" in text, text
    assert read_card(ck).epochs == {"semantic": 1}


@pytest.mark.parametrize("kind", ["adapt", "imported"])
def test_train_resume_into_an_adaptation_or_import_is_refused(kind, logs, ck):
    """Finding: `train dsnet --resume` into an adapted checkpoint overwrote it with a card mixing both."""
    card = json.loads((ck / "card.json").read_text())
    card["training_data"][kind] = {"rounds": []} if kind == "adapt" else {"kind": "dsnet"}
    (ck / "card.json").write_text(card_text(card))
    code, text = invoke("train", "dsnet", logs[0], "--out", ck, "--epochs", "semantic=2", *TRAIN, "--resume")
    assert code == 2, text
    want = (
        "is an adapted checkpoint (written by dsnet adapt)"
        if kind == "adapt"
        else "is an imported checkpoint"
    )
    assert want in text and f"--init-from {ck}" in text


def test_adapt_resume_of_a_finished_adaptation_with_other_logs_is_refused(logs, tmp_path):
    """Finding: `adapt V16 --out ck/ad1 --resume` on an adaptation to U said "wrote adapted
    checkpoint", adapted to nothing new."""
    parent = make_checkpoint(tmp_path / "parent")
    out = Path(shutil.copytree(parent, tmp_path / "ad1"))
    card = json.loads((out / "card.json").read_text())
    card["training_data"]["adapt"] = {
        "method": "dsnet",
        "logs": [{"root": str(logs[0].resolve())}],
        "parent": {"path": str(parent.resolve())},
        "rounds": [],
    }
    (out / "card.json").write_text(card_text(card))
    code, text = invoke("adapt", logs[1], "--out", out, "--resume")
    assert code == 2, text
    assert (
        f"{out} was adapted with other logs or settings: LOG: {logs[0].resolve()} → {logs[1].resolve()}"
        in text
    )


# -- import-checkpoint -------------------------------------------------------------------------------
def test_import_over_a_trained_folder_is_refused_and_over_an_import_replaces_it(
    reference_files, ck, tmp_path
):
    """Finding: an import over a trained folder replaced its weights and card, leaving its train state."""
    weights = (ck / "model.safetensors").read_bytes()
    code, text = invoke("import-checkpoint", reference_files[0], "--out", ck, "--kind", "dsnet")
    assert code == 2 and "holds a trained checkpoint (dsnet train)" in text, text
    assert (ck / "model.safetensors").read_bytes() == weights
    out = tmp_path / "imp"
    assert invoke("import-checkpoint", reference_files[0], "--out", out, "--kind", "dsnet")[0] == 0
    code, text = invoke("import-checkpoint", reference_files[1], "--out", out, "--kind", "cylinder3d")
    assert code == 0, text
    assert text.splitlines()[-1] == f"replaced the earlier import in {out.resolve()} (of dsnet.pth)"
    assert read_card(out).training_data["imported"]["kind"] == "cylinder3d"
    assert not (out / "shift.safetensors").exists()  # the earlier import's shifting MLPs went with it


def test_import_of_a_folder_or_a_safetensors_file_says_what_to_do(trained, tmp_path):
    """Finding: a folder that exists was "no such file"; a safetensors file "not a torch checkpoint"."""
    code, text = invoke("import-checkpoint", trained, "--out", tmp_path / "x", "--kind", "dsnet")
    assert (
        code == 2 and "is a folder holding this product's checkpoint (card.json): it needs no import" in text
    )
    (tmp_path / "empty").mkdir()
    code, text = invoke("import-checkpoint", tmp_path / "empty", "--out", tmp_path / "x", "--kind", "dsnet")
    assert code == 2 and "is a folder: import-checkpoint reads one released file (*.pth / *.pt)" in text
    code, text = invoke(
        "import-checkpoint", trained / "model.safetensors", "--out", tmp_path / "x", "--kind", "dsnet"
    )
    assert code == 2 and "is a safetensors file, not a torch checkpoint" in text, text
    assert "this product's own checkpoints are folders (model.safetensors + card.json)" in text


def test_integer_weights_are_refused_by_the_import(tmp_path):
    """Finding: int64 weights imported without a word (their values truncated)."""
    state = spconv1_state(randomize(DSNetReference(4)).state_dict())
    key = next(k for k, v in state.items() if v.is_floating_point() and v.dim() == 5)
    state[key] = state[key].to(torch.int64)
    src = tmp_path / "int.pth"
    torch.save({"model_state": state}, src)
    with pytest.raises(
        CheckpointImportError, match=rf"1 weight\(s\) are not floating point: {key} \(int64\)"
    ):
        from dsnet_core.model.importer import import_checkpoint

        import_checkpoint(src, tmp_path / "out", "dsnet")


def test_a_semantics_only_import_is_refused_for_labelling(logs, reference_files, tmp_path):
    """Finding: `label --checkpoint` of a cylinder3d import labelled instances with an untrained head."""
    out = tmp_path / "cyl"
    assert invoke("import-checkpoint", reference_files[1], "--out", out, "--kind", "cylinder3d")[0] == 0
    code, text = invoke("label", logs[0], "--run", tmp_path / "run", "--scans", "1", "--checkpoint", out)
    assert code == 2 and text.count("\n") == 1, text
    assert f"{out / 'card.json'}: semantics only (an imported cylinder3d network)" in text
    assert f"dsnet train dsnet DATA --init-from {out} --out NEW" in text and "Prefect" not in text
    assert not (tmp_path / "run").exists()


def test_a_checkpoint_with_nan_weights_is_refused_when_loaded(ck):
    """Finding: a NaN checkpoint failed in shift with "positions hold NaN or inf", naming no file."""
    model, card = load_checkpoint(ck)
    with torch.no_grad():
        next(model.parameters()).view(-1)[3] = float("nan")
    save_checkpoint(ck, model, card)
    with pytest.raises(
        CheckpointError, match=r"model\.safetensors: weights hold NaN or infinite values \(1 tensor"
    ):
        load_checkpoint(ck)


# -- Ctrl-C during adapt ---------------------------------------------------------------------------
def _adapt_ctrl_c(tmp_path, phase: str):
    """``dsnet adapt`` (random parent, two corrected frames, the synthetic stream with one worker),
    SIGINT to its process group (what Ctrl-C sends) once ``phase`` is reached."""
    import time

    from tests.flows.conftest import REPO, cli
    from tests.flows.test_adapt_cli import FAST_SHIFT, corrections, unlabelled

    labelled = write_tiny_log(tmp_path / "labelled", frames=3, n=1500)
    fixes = corrections(labelled, tmp_path / "fixes", ["000000", "000002"])
    target = unlabelled(write_tiny_log(tmp_path / "target", frames=3, n=1500))
    parent = make_checkpoint(tmp_path / "parent")
    out = tmp_path / "ad"
    args = ["adapt", target, "--out", out, "--from", parent, "--labels", fixes, "--clusterer", FAST_SHIFT]
    args = [
        str(a) for a in (*args, "--steps", "6", "--rounds", "1", "--epochs", "2", "--stream-workers", "1")
    ]
    env = {**os.environ, "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1"}
    proc = subprocess.Popen(
        cli(*args), cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        start_new_session=True,
    )  # fmt: skip

    def reached() -> bool:
        if phase == "teacher":
            return (out / "store").is_dir()
        children = subprocess.run(
            ["ps", "-o", "cmd", "--ppid", str(proc.pid)], capture_output=True, text=True
        )
        return "spawn_main" in children.stdout  # the stream's render worker runs

    deadline = time.monotonic() + 600
    while not reached() and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    assert proc.poll() is None, proc.communicate()[1][-2000:]
    os.killpg(proc.pid, signal.SIGINT)
    _, err = proc.communicate(timeout=300)
    return proc, err, args, env


def _assert_one_line(proc, err: str) -> None:
    lines = [ln for ln in err.replace("\r", "\n").splitlines() if ln.strip() and "━" not in ln]
    assert proc.returncode == 130, err[-3000:]
    assert "Traceback" not in err and "KeyboardInterrupt" not in err, err[-3000:]
    assert [ln for ln in lines if "error" in ln.lower()] == [
        "error: interrupted; the finished epochs are kept: run the same command with --resume to continue"
    ]


def test_ctrl_c_in_adapts_teacher_phase_says_one_line(tmp_path):
    """Finding: Ctrl-C in the teacher phase exited silently."""
    proc, err, _, _ = _adapt_ctrl_c(tmp_path, "teacher")
    _assert_one_line(proc, err)
    assert not (tmp_path / "ad" / LOCK).exists()


@pytest.mark.slow
def test_ctrl_c_while_adapts_stream_worker_runs_says_one_line_and_resumes(tmp_path):
    """Finding: a 20-line ``SpawnProcess … KeyboardInterrupt`` traceback from the stream's worker."""
    from tests.flows.conftest import REPO, cli

    proc, err, args, env = _adapt_ctrl_c(tmp_path, "stream")
    _assert_one_line(proc, err)
    again = subprocess.run(
        cli(*args, "--resume"), cwd=REPO, env=env, capture_output=True, text=True, timeout=600
    )
    assert again.returncode == 0 and "wrote adapted checkpoint" in again.stdout, again.stderr[-2000:]
    assert (
        "relabel: dsnet label LOG --run RUN --refine --scans 1 --checkpoint" in again.stdout
    )  # k of the card


# -- damage to a training folder ---------------------------------------------------------------------
@pytest.mark.parametrize("damage", ["json", "truncated", "bit-flip"])
def test_a_damaged_optimiser_state_is_refused_naming_the_file(damage, logs, ck):
    """Issue 40 ("Also"): damage to ``train_state`` must give a clear refusal, never a silent mix (a
    bad JSON was "Expecting value" naming no file, a truncated tensor file a traceback, a flipped bit
    went unnoticed)."""
    state = ck / ("train_state.json" if damage == "json" else "train_state.safetensors")
    data = bytearray(state.read_bytes())
    if damage == "json":
        data = data[:10]
    elif damage == "truncated":
        data = data[: len(data) // 2]
    else:
        data[-3] ^= 0x01
    state.write_bytes(bytes(data))
    code, text = invoke("train", "dsnet", logs[0], "--out", ck, "--epochs", "semantic=2", *TRAIN, "--resume")
    lines = [ln for ln in text.splitlines() if ln.strip()]
    assert code == 2 and len(lines) == 1, text
    assert lines[0].startswith(f"error: {state}: optimiser state")
    assert "delete train_state.json and train_state.safetensors to resume with a fresh optimiser" in text
    assert read_card(ck).epochs == {"semantic": 1}


def test_label_takes_its_default_scans_from_the_checkpoints_card(trained, reference_files, tmp_path):
    """Finding: adapt trains at k = 1 and `label` defaulted to k = 2, so the suggested relabel fed
    2-scan volumes to a single-scan model. Without --scans, label now takes the card's k."""
    from tasks.methods import LabelSettings, get_method

    dsnet = get_method("dsnet")
    assert dsnet.scans(LabelSettings(checkpoint=str(trained))) == 1  # trained (or adapted) at k = 1
    assert dsnet.scans(LabelSettings(checkpoint=str(trained), scans=3)) == 3  # --scans wins
    assert (
        dsnet.scans(LabelSettings(checkpoint=str(make_checkpoint(tmp_path / "r")))) == 2
    )  # card says nothing
    assert dsnet.scans(LabelSettings()) == 2
    out = tmp_path / "imp"
    assert invoke("import-checkpoint", reference_files[0], "--out", out, "--kind", "dsnet")[0] == 0
    assert dsnet.scans(LabelSettings(checkpoint=str(out))) == 1  # a 3D DS-Net import
