"""Reading a reference checkpoint: only what torch.save writes, read with weights_only=True; every
refusal is one line naming the file."""

from __future__ import annotations

import io
import os
import zipfile

import numpy as np
import pytest
import torch

from dsnet_core.errors import CheckpointImportError
from dsnet_core.model.reference_file import load_reference_file


def refused(path) -> str:
    with pytest.raises(CheckpointImportError) as err:
        load_reference_file(path)
    msg = str(err.value)
    assert msg.startswith(f"{path}: ") and "\n" not in msg
    return msg.removeprefix(f"{path}: ")


@pytest.mark.parametrize(
    ("name", "body", "starts"),
    [
        ("notes.pth", b"epoch 5, PQ 0.577\nthe weights are elsewhere\n", "b'epoch 5, PQ '"),
        ("random.pth", np.random.default_rng(0).bytes(4096), None),
        ("empty.pth", b"", "an empty file"),
    ],
)
def test_what_torch_did_not_write_is_not_a_torch_checkpoint(tmp_path, name, body, starts):
    (tmp_path / name).write_bytes(body)
    msg = refused(tmp_path / name)
    assert msg.startswith("not a torch checkpoint: neither torch.save's zip archive nor its legacy pickle")
    if starts:
        assert starts in msg


def test_a_foreign_or_damaged_zip_is_not_a_torch_checkpoint(tmp_path):
    with zipfile.ZipFile(tmp_path / "other.zip", "w") as z:
        z.writestr("weights.txt", "1 2 3")
    assert refused(tmp_path / "other.zip") == (
        "not a torch checkpoint: a zip archive without torch.save's data.pkl"
    )
    buf = io.BytesIO()
    torch.save({"model_state": {"a": torch.ones(3)}}, buf)
    (tmp_path / "cut.pth").write_bytes(buf.getvalue()[: len(buf.getvalue()) // 2])
    assert refused(tmp_path / "cut.pth").startswith(
        "not a torch checkpoint: a zip archive that cannot be read (truncated?)"
    )


def test_a_damaged_legacy_pickle_is_not_readable(tmp_path):
    buf = io.BytesIO()
    torch.save({"model_state": {"a": torch.ones(3)}}, buf, _use_new_zipfile_serialization=False)
    raw = buf.getvalue()
    (tmp_path / "cut.pth").write_bytes(raw[:-4])  # a download cut short in the tensor data
    assert refused(tmp_path / "cut.pth") == (
        "not a readable torch checkpoint (truncated?): unexpected EOF, expected 4 more bytes. "
        "The file might be corrupted."
    )
    (tmp_path / "garbled.pth").write_bytes(raw[:16] + os.urandom(300))
    assert refused(tmp_path / "garbled.pth").startswith("not a readable torch checkpoint")


def test_arbitrary_objects_are_refused_in_one_line(tmp_path):
    torch.save(
        {"model_state": {"a": torch.zeros(1)}, "other_state": zipfile.ZipInfo("x")}, tmp_path / "o.pth"
    )
    msg = refused(tmp_path / "o.pth")
    assert msg.startswith("the file needs unpickling of arbitrary Python objects")
    assert "Unsupported global: GLOBAL zipfile.ZipInfo" in msg and "no fallback" in msg


@pytest.mark.parametrize("zipped", [True, False])
def test_both_torch_formats_are_read(tmp_path, zipped):
    obj = {"epoch": 5, "model_state": {"module.a": torch.arange(3.0)}, "other_state": {"pq": np.float64(0.5)}}
    torch.save(obj, tmp_path / "f.pth", _use_new_zipfile_serialization=zipped)
    state, info = load_reference_file(tmp_path / "f.pth")
    assert list(state) == ["a"] and torch.equal(state["a"], torch.arange(3.0))
    assert info == {"top_level_keys": ["epoch", "model_state", "other_state"], "epoch": 5}


def test_a_legacy_file_torch_cannot_read_safely_is_refused_as_such(tmp_path):
    """torch's weights-only unpickler lacks protocol 4's FRAME opcode (149): a torch file, unreadable."""
    torch.save(
        {"a": torch.ones(2)}, tmp_path / "p4.pth", _use_new_zipfile_serialization=False, pickle_protocol=4
    )
    assert refused(tmp_path / "p4.pth") == (
        "not a readable torch checkpoint: torch.load(weights_only=True) cannot read its pickle "
        "(Unsupported operand 149): damaged, or a pickle protocol it does not support"
    )
