"""What the model-folder fuzz (``tests/flows/folder_fuzz.py``, slow) found, one fast test a finding:
each damage gives one typed line naming the damaged file, before any training or server."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from typer.testing import CliRunner

from dsnet_core.errors import CheckpointError
from dsnet_core.model.card import card_text
from flows.cli import app
from tests.dsnet_core.adapt.test_trainer import trainer, world  # noqa: F401 - world: a fixture
from tests.helpers.tiny_log import write_tiny_log
from tests.model_helpers import make_checkpoint

TRAIN = ("--stage", "semantic", "--grid", "24,32,8", "--threads", "1")


def invoke(*args) -> tuple[int, str]:
    res = CliRunner().invoke(app, [str(a) for a in args])
    return res.exit_code, res.output


@pytest.fixture(scope="module")
def log(tmp_path_factory):
    return write_tiny_log(tmp_path_factory.mktemp("log") / "a", frames=2)


@pytest.fixture(scope="module")
def trained(log, tmp_path_factory):
    out = tmp_path_factory.mktemp("trained") / "ck"
    code, text = invoke("train", "dsnet", log, "--out", out, "--epochs", "semantic=1", *TRAIN)
    assert code == 0, text
    return out


@pytest.fixture
def ck(trained, tmp_path):
    return Path(shutil.copytree(trained, tmp_path / "ck"))


def one_error(text: str) -> str:
    lines = [ln for ln in text.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), text
    return lines[0]


@pytest.mark.parametrize("lost", ["train_state.json", "train_state.safetensors"])
def test_a_resume_missing_half_of_the_optimiser_state_is_refused(lost, log, ck):
    """Found: either half deleted → the resume went on with a fresh optimiser, exit 0, weights
    unlike an uninterrupted run's. (Both deleted stays the documented way to a fresh optimiser.)"""
    (ck / lost).unlink()
    code, text = invoke("train", "dsnet", log, "--out", ck, "--epochs", "semantic=2", *TRAIN, "--resume")
    assert code == 2
    assert one_error(text).startswith(f"error: {ck / lost}: optimiser state is missing, its other half")


@pytest.mark.parametrize("command", ["train", "import"])
def test_a_folder_whose_card_is_lost_is_refused(command, log, ck, tmp_path):
    """Found: a trained folder without its card was trained afresh over by ``--resume`` and imported
    into by ``import-checkpoint`` (which left its train state beside the import's weights)."""
    (ck / "card.json").unlink()
    weights = (ck / "model.safetensors").read_bytes()
    if command == "train":
        args = ("train", "dsnet", log, "--out", ck, "--epochs", "semantic=1", *TRAIN, "--resume")
        want = f"error: {ck / 'card.json'}: no model card beside model.safetensors, train_state.json"
    else:
        released = tmp_path / "r.pth"
        released.write_bytes(b"never read")
        args = ("import-checkpoint", released, "--out", ck, "--kind", "dsnet")
        want = (
            f"error: {ck} holds metrics.csv, metrics.json, train_state.json, train_state.safetensors but no"
        )
    code, text = invoke(*args)
    assert code == 2 and one_error(text).startswith(want), text
    assert (ck / "model.safetensors").read_bytes() == weights


@pytest.mark.parametrize("damage", ["flip", "delete"])
@pytest.mark.parametrize("name", ["model.safetensors", "shift.safetensors"])
def test_label_refuses_damaged_weights_before_any_server(name, damage, log, tmp_path):
    """Found: damaged weights were found by the infer stage, after a Prefect server had started."""
    ck = make_checkpoint(tmp_path / "ck")
    if damage == "delete":
        (ck / name).unlink()
    else:
        data = bytearray((ck / name).read_bytes())
        data[len(data) // 2] ^= 0x10
        (ck / name).write_bytes(bytes(data))
    code, text = invoke("label", log, "--run", tmp_path / "run", "--scans", "1", "--checkpoint", ck)
    assert code == 2 and one_error(text).startswith(f"error: {ck / name}: "), text
    assert ("missing though the model card records it" if damage == "delete" else "sha256") in text
    assert "Prefect" not in text and not (tmp_path / "run").exists()


def test_adapt_resume_names_the_folders_damaged_file_not_a_rounds_copy(log, tmp_path):
    """Found: a damaged ``OUT/shift.safetensors`` was reported as ``OUT/rounds/2/teacher/shift…``,
    the copy the next round's teacher snapshot had made of it."""
    out = make_checkpoint(tmp_path / "ad")
    card = json.loads((out / "card.json").read_text())
    card["training_data"]["adapt"] = {"method": "dsnet", "logs": [{"root": str(log.resolve())}], "rounds": []}
    (out / "card.json").write_text(card_text(card))
    data = bytearray((out / "shift.safetensors").read_bytes())
    data[-2] ^= 0x01
    (out / "shift.safetensors").write_bytes(bytes(data))
    code, text = invoke("adapt", log, "--out", out, "--resume", "--steps", "2", "--epochs", "1")
    assert code == 2, text
    assert one_error(text).startswith(f"error: {out / 'shift.safetensors'}: shifting weights do not match")


@pytest.mark.parametrize("damage", ["flip", "truncate", "delete"])
def test_a_damaged_student_is_refused_by_the_adaptation_naming_it(damage, world, tmp_path):  # noqa: F811
    """Found: a truncated or deleted ``student.safetensors`` was a traceback, a flipped bit trained
    on silently (the card recorded no digest of the student; it now does)."""
    from dsnet_core.adapt import AdaptConfig
    from dsnet_core.adapt.trainer import STUDENT

    out = tmp_path / "ad"
    trainer(world, out, AdaptConfig(rounds=1, steps=2, epochs=1, seed=4, patience=0)).run()
    assert len(json.loads((out / "card.json").read_text())["training_data"]["adapt"]["student_sha256"]) == 64
    student = out / STUDENT
    data = bytearray(student.read_bytes())
    if damage == "delete":
        student.unlink()
    elif damage == "truncate":
        student.write_bytes(bytes(data[: len(data) // 2]))
    else:
        data[-5] ^= 0x04
        student.write_bytes(bytes(data))
    want = "are missing" if damage == "delete" else "do not match the model card's record"
    with pytest.raises(CheckpointError, match=rf"student\.safetensors: the student's weights {want}"):
        trainer(world, out, AdaptConfig(rounds=2, steps=2, epochs=1, seed=4, patience=0), resume=True)
