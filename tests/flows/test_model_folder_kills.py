"""Issue 40 ("Also"): the kill suite over model folders. A real ``dsnet`` subprocess is SIGKILLed
just before a chosen file lands in its ``--out`` folder (every file there is moved into place with
``os.replace``, so each move is a commit point: :func:`tests.helpers.kill.dsnet_killed_at_replace`),
enumerated or drawn at seeded random:

- ``dsnet train dsnet`` and ``dsnet adapt``: ``--resume`` ends with tensors equal, bit for bit, to an
  uninterrupted run's; until then a reader (``load_checkpoint``, what ``label --checkpoint`` does)
  refuses a folder whose epoch was killed half-saved, naming it;
- ``dsnet import-checkpoint`` (a fresh folder, and over an earlier import): the folder afterwards
  holds no checkpoint (a refusal naming the file) or a complete one, never a mix of two imports.

The first case of each is fast; the enumerations are ``slow``.
"""

from __future__ import annotations

import json
import random
import shutil
import signal
from pathlib import Path

import pytest
import torch
from safetensors.torch import load_file
from typer.testing import CliRunner

from dsnet_core.errors import CheckpointError
from dsnet_core.model.bundle import load_shift_weights
from dsnet_core.model.checkpoint import load_checkpoint, read_card
from flows.cli import app
from tests.helpers.kill import dsnet_killed_at_replace
from tests.helpers.tiny_log import write_tiny_log

KILLED = -signal.SIGKILL
TRAIN = ("--grid", "24,32,8", "--threads", "1", "--lr", "0.01", "--no-augment")


def invoke(*args) -> tuple[int, str]:
    res = CliRunner().invoke(app, [str(a) for a in args])
    return res.exit_code, res.output


def tensors(folder: Path, *names: str) -> dict[str, dict[str, torch.Tensor]]:
    """Every tensor of the named safetensors files of ``folder`` (absent files: empty)."""
    return {n: load_file(str(folder / n)) if (folder / n).is_file() else {} for n in names}


def assert_same_tensors(a: Path, b: Path, *names: str) -> None:
    ta, tb = tensors(a, *names), tensors(b, *names)
    for name in names:
        assert ta[name].keys() == tb[name].keys(), name
        for key, value in ta[name].items():
            assert value.dtype == tb[name][key].dtype and torch.equal(value, tb[name][key]), (name, key)
        assert (a / name).read_bytes() == (b / name).read_bytes(), name


def moves(trace: Path) -> list[str]:
    return trace.read_text().splitlines()


# -- dsnet train dsnet ---------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def log(tmp_path_factory):
    return write_tiny_log(tmp_path_factory.mktemp("log") / "log", frames=2)


def _train_args(log: Path, out: Path, epochs: str, stage: str) -> list:
    return ["train", "dsnet", log, "--out", out, "--stage", stage, "--epochs", epochs, *TRAIN]


def test_a_training_killed_between_an_epochs_files_is_refused_then_resumes_bit_identically(log, tmp_path):
    """SIGKILL after epoch 2's card moved into place and before its weights did (the folder then
    holds epoch 2's card with epoch 1's weights): a reader refuses it, naming the interrupted save
    (was: "weights do not match the model card's sha256 (tampered …)"); ``--resume`` finishes the
    save and the weights equal an uninterrupted run's."""
    args = ("semantic=2", "semantic")
    straight = tmp_path / "straight"
    code, text = invoke(*_train_args(log, straight, *args))
    assert code == 0, text
    killed = tmp_path / "killed"
    res = dsnet_killed_at_replace(killed, "model.safetensors:2", _train_args(log, killed, *args))
    assert res.returncode == KILLED, res.stderr[-2000:]
    assert (killed / ".pending" / "COMMIT").is_file() and not (killed / ".pending" / "card.json").exists()
    assert json.loads((killed / "card.json").read_text())["epochs"] == {"semantic": 2}  # moved first
    with pytest.raises(CheckpointError, match=r"\.pending: an epoch is being saved here, or its save was"):
        load_checkpoint(killed)
    code, text = invoke("label", log, "--run", tmp_path / "run", "--scans", "1", "--checkpoint", killed)
    assert code == 2 and text.count("\n") == 1 and "finish the save with the same `dsnet train`" in text
    assert not (tmp_path / "run").exists()
    code, text = invoke(*_train_args(log, killed, *args), "--resume")
    assert code == 0, text
    assert read_card(killed).epochs == {"semantic": 2}
    assert_same_tensors(killed, straight, "model.safetensors", "train_state.safetensors")


@pytest.mark.slow
@pytest.mark.timeout(1800)
def test_a_training_killed_at_seeded_random_file_moves_resumes_bit_identically(log, tmp_path):
    """Three stages (the shift stage writes ``shift.safetensors``), a kill before each of eight
    moves drawn at seeded random from the uninterrupted run's (staged files, the commit marker and
    the moves into place), each followed by ``--resume``: identical weights every time."""
    args = ("semantic=1,offset=1,shift=1", "all")
    straight, trace = tmp_path / "straight", tmp_path / "trace"
    res = dsnet_killed_at_replace(straight, 0, _train_args(log, straight, *args), trace=trace)
    assert res.returncode == 0, res.stderr[-2000:]
    landed = moves(trace)
    assert landed.count(".pending/COMMIT") == 3 and "shift.safetensors" in landed
    for at in sorted(random.Random(40).sample(range(1, len(landed) + 1), 8)):
        killed = tmp_path / f"killed{at}"
        res = dsnet_killed_at_replace(killed, at, _train_args(log, killed, *args))
        assert res.returncode == KILLED, f"kill before move {at} ({landed[at - 1]}): {res.stderr[-2000:]}"
        code, text = invoke(*_train_args(log, killed, *args), "--resume")
        assert code == 0, f"move {at} ({landed[at - 1]}): {text}"
        assert read_card(killed).epochs == {"semantic": 1, "offset": 1, "shift": 1}
        assert_same_tensors(killed, straight, "model.safetensors", "shift.safetensors")
        shutil.rmtree(killed)


# -- dsnet adapt -----------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def adapt_inputs(tmp_path_factory):
    """A random-weight parent, one corrected frame, a 3-frame unlabelled target and a source log."""
    from tests.flows.test_adapt_cli import corrections, unlabelled
    from tests.model_helpers import make_checkpoint

    root = tmp_path_factory.mktemp("adapt")
    labelled = write_tiny_log(root / "labelled", frames=3, n=1000)
    return {
        "fixes": corrections(labelled, root / "fixes", ["000001"]),
        "target": unlabelled(write_tiny_log(root / "target", frames=3, n=1000)),
        "source": write_tiny_log(root / "source", frames=2, n=1000, seed=1),
        "parent": make_checkpoint(root / "parent", seed=3),
    }


def _adapt_args(inputs: dict, out: Path) -> list:
    from tests.flows.test_adapt_cli import FAST_SHIFT

    return [
        "adapt", inputs["target"], "--out", out, "--from", inputs["parent"], "--labels", inputs["fixes"],
        "--source-log", inputs["source"], "--rounds", "2", "--steps", "2", "--epochs", "1",
        "--clusterer", FAST_SHIFT, "--lr", "0.01", "--threads", "1",
    ]  # fmt: skip


ADAPT_FILES = ("model.safetensors", "student.safetensors", "train_state.safetensors")


@pytest.mark.slow
@pytest.mark.timeout(2400)
def test_an_adaptation_killed_at_seeded_random_file_moves_resumes_bit_identically(adapt_inputs, tmp_path):
    """Two rounds (teacher labelling into ``OUT/store``, pseudo-labels into ``OUT/rounds/R``, one
    student epoch each): kills before round 1's first store write, round 2's teacher snapshot, each
    round's epoch between its card and its weights, and three moves drawn at seeded random; each
    ``--resume`` ends with the teacher's, the student's and the optimiser's tensors equal to an
    uninterrupted run's."""
    straight, trace = tmp_path / "straight", tmp_path / "trace"
    res = dsnet_killed_at_replace(straight, 0, _adapt_args(adapt_inputs, straight), trace=trace)
    assert res.returncode == 0, res.stderr[-3000:]
    landed = moves(trace)
    first_store = next(i for i, m in enumerate(landed, 1) if m.startswith("store/"))
    points: list[int | str] = [
        first_store,
        "rounds/2/teacher:1",
        "model.safetensors:1",
        "model.safetensors:2",
    ]
    points += sorted(random.Random(40).sample(range(1, len(landed) + 1), 3))
    for at in points:
        where = at if isinstance(at, str) else f"move {at} ({landed[at - 1]})"
        killed = tmp_path / "killed"
        res = dsnet_killed_at_replace(killed, at, _adapt_args(adapt_inputs, killed))
        assert res.returncode == KILLED, f"kill before {where}: {res.stderr[-2000:]}"
        code, text = invoke(*_adapt_args(adapt_inputs, killed), "--resume")
        assert code == 0, f"{where}: {text[-3000:]}"
        assert read_card(killed).epochs == {"round1": 1, "round2": 1}, where
        assert_same_tensors(killed, straight, *ADAPT_FILES)
        shutil.rmtree(killed)


# -- dsnet import-checkpoint -----------------------------------------------------------------------------
@pytest.fixture(scope="module")
def released(tmp_path_factory):
    """Two released DS-Net files (random weights, with shifting MLPs), spconv 1.x layout."""
    from tests.dsnet_core.model.reference_net import DSNetReference, randomize, spconv1_state

    root = tmp_path_factory.mktemp("released")
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    files = []
    for seed in (0, 1):
        state = spconv1_state(randomize(DSNetReference(4), seed=seed).state_dict())
        torch.save({"epoch": 1, "model_state": state}, root / f"dsnet{seed}.pth")
        files.append(root / f"dsnet{seed}.pth")
    torch.set_num_threads(before)
    return files


def _import_args(src: Path, out: Path) -> list:
    return ["import-checkpoint", src, "--out", out, "--kind", "dsnet"]


def _imported(folder: Path) -> tuple[dict, dict]:
    model, _ = load_checkpoint(folder)
    return {k: v.clone() for k, v in model.state_dict().items()}, load_shift_weights(folder) or {}


def _same(a: dict, b: dict) -> bool:
    return a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)


def _check_killed_import(out: Path, complete: list[tuple[dict, dict]], src: Path, want: tuple) -> str:
    """``out`` after a killed import: no checkpoint (a refusal naming a file of it) or one of the
    ``complete`` imports, whole; then a rerun of the import completes it to ``want``."""
    try:
        model, shift = _imported(out)
    except CheckpointError as exc:
        assert str(out) in str(exc)
        seen = "refused"
    else:
        found = [i for i, (m, s) in enumerate(complete) if _same(model, m) and _same(shift, s)]
        assert found, f"{out} loads as a mix of two imports"
        seen = f"complete import {found[0]}"
    code, text = invoke(*_import_args(src, out))
    assert code == 0, text
    model, shift = _imported(out)
    assert _same(model, want[0]) and _same(shift, want[1])
    return seen


def test_an_import_killed_over_an_earlier_import_leaves_no_mix(released, tmp_path):
    """SIGKILL after the new shifting weights landed, before the new weights did (was: the earlier
    import's card rewritten to cover the new shifting weights, so the folder loaded as a complete
    checkpoint of the old network with the new one's shifting MLPs)."""
    first, second = tmp_path / "first", tmp_path / "second"
    assert invoke(*_import_args(released[0], first))[0] == 0
    assert invoke(*_import_args(released[1], second))[0] == 0
    complete = [_imported(first), _imported(second)]
    res = dsnet_killed_at_replace(first, "model.safetensors:1", _import_args(released[1], first))
    assert res.returncode == KILLED, res.stderr[-2000:]
    with pytest.raises(CheckpointError, match=r"card\.json: no model card beside model\.safetensors"):
        load_checkpoint(first)
    assert _check_killed_import(first, complete, released[1], complete[1]) == "refused"


@pytest.mark.slow
@pytest.mark.timeout(900)
@pytest.mark.parametrize("over", ["fresh", "earlier"])
def test_an_import_killed_before_any_of_its_moves_leaves_none_or_a_complete_one(over, released, tmp_path):
    """Every move of an import (fresh, and over an earlier import of another file) as a kill point."""
    earlier, want = tmp_path / "earlier", tmp_path / "want"
    assert invoke(*_import_args(released[0], earlier))[0] == 0
    assert invoke(*_import_args(released[1], want))[0] == 0
    complete = [_imported(earlier), _imported(want)]
    trace, probe = tmp_path / "trace", tmp_path / "probe"
    if over == "earlier":
        shutil.copytree(earlier, probe)
    res = dsnet_killed_at_replace(probe, 0, _import_args(released[1], probe), trace=trace)
    assert res.returncode == 0, res.stderr[-2000:]
    landed = moves(trace)
    assert landed[-1] == "card.json" and "shift.safetensors" in landed
    for at in range(1, len(landed) + 1):
        out = tmp_path / f"out{at}"
        if over == "earlier":
            shutil.copytree(earlier, out)
        res = dsnet_killed_at_replace(out, at, _import_args(released[1], out))
        assert res.returncode == KILLED, res.stderr[-2000:]
        seen = _check_killed_import(out, complete, released[1], complete[1])
        assert seen == "refused", (at, seen)  # the earlier import's card goes before any move


def test_under_torchrun_the_other_ranks_read_the_card_once_rank_0_finished_the_moves(
    log, tmp_path, monkeypatch
):
    """A resume after a kill between an epoch's commit and its moves: rank 0 rolls the epoch forward;
    a rank ≠ 0 reading the card meanwhile would be refused (the folder mixes two epochs), so it
    waits for the moves to end, then checks the resume as rank 0 does."""
    import os
    import threading
    import time

    from tasks.methods import get_method
    from tasks.methods.resume import check_train_resume

    out = tmp_path / "ck"
    args = ("semantic=1", "semantic")
    code, text = invoke(*_train_args(log, out, *args))
    assert code == 0, text
    pending = out / ".pending"
    pending.mkdir()
    os.replace(out / "card.json", pending / "card.json")
    (pending / "COMMIT").write_text(json.dumps(["card.json"]))

    def rank_0_rolls_forward() -> None:
        time.sleep(0.5)
        os.replace(pending / "card.json", out / "card.json")
        shutil.rmtree(pending)

    mover = threading.Thread(target=rank_0_rolls_forward)
    mover.start()
    monkeypatch.setenv("RANK", "1")
    options = get_method("dsnet").TrainOptions(
        data=log, out=out, stage="semantic", epochs="semantic=1", grid="24,32,8", threads=1, lr=0.01,
        augment=False, resume=True,
    )  # fmt: skip
    check_train_resume(options)  # no "an epoch is being saved here" refusal
    mover.join()
    assert not pending.exists() and read_card(out).epochs == {"semantic": 1}
