"""``dsnet import-checkpoint`` on a reconstructed reference file and on files in the layout the
reference saves (``tests/dsnet_core/model/fixtures/reference_state_dicts.json``, recorded from
hongfz16/DS-Net at commit 4a73e2fe529798ad4ec3256d89411f59d2c10416), then ``dsnet label`` with the
imported model; relabelling with another checkpoint recomputes infer onward only."""

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from dsnet_core.model.checkpoint import read_card, sha256_file
from flows.cli import app
from tests.dsnet_core.model.recorded import random_state, save_wrapped
from tests.dsnet_core.model.reference_net import (
    Cylinder3DReference,
    DSNetReference,
    randomize,
    spconv1_state,
)
from tests.helpers.label_request import req
from tests.helpers.tiny_log import write_tiny_log


@pytest.fixture(scope="module")
def reference_file(tmp_path_factory):
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    path = tmp_path_factory.mktemp("ref") / "dsnet_pretrain.pth"
    state = spconv1_state(randomize(DSNetReference(4), seed=0).state_dict())
    torch.save({"epoch": 3, "model_state": state, "optimizer_state": None, "other_state": {}}, path)
    torch.set_num_threads(before)
    return path


def test_import_checkpoint_command(reference_file, tmp_path):
    res = CliRunner().invoke(
        app, ["import-checkpoint", str(reference_file), "--out", str(tmp_path / "ckpt"), "--kind", "dsnet"]
    )
    assert res.exit_code == 0, res.output
    lines = res.output.splitlines()
    assert lines[0] == f"wrote checkpoint {(tmp_path / 'ckpt').resolve()}"
    sha = sha256_file(reference_file)[:12]
    assert lines[1] == f"  source: dsnet_pretrain.pth (sha256 {sha}, epoch 3)"
    assert lines[2:9] == [
        "  kind: dsnet",
        "  width: 4 (20 classes)",
        "  layout: spconv 1.x (*kernel, in, out), spconv1-shared rulebooks",
        "  grid convention: reference",
        "  converted: 51 sparse convolutions, 51 batch norms, 15 linear layers, 4 shifting iterations",
        "  dropped buffers: sem_loss.weight (20,) (class weights of the semantic loss (CrossEntropyLoss), "
        "used in training only)",
        "  dropped kernel taps: 4 weights beyond their shared rulebook's taps",
    ]
    assert read_card(tmp_path / "ckpt").training_data["imported"]["kind"] == "dsnet"
    bad = CliRunner().invoke(
        app, ["import-checkpoint", str(reference_file), "--out", str(tmp_path / "x"), "--kind", "cylinder3d"]
    )
    assert bad.exit_code == 2 and "error:" in bad.output and "unknown keys" in bad.output


def test_a_cylinder3d_file_prints_semantics_only_and_no_dropped_buffers(tmp_path):
    torch.save(spconv1_state(randomize(Cylinder3DReference(4), seed=1).state_dict()), tmp_path / "c.pt")
    res = CliRunner().invoke(
        app,
        ["import-checkpoint", str(tmp_path / "c.pt"), "--out", str(tmp_path / "o"), "--kind", "cylinder3d"],
    )
    assert res.exit_code == 0, res.output
    lines = res.output.splitlines()
    assert lines[1].endswith(")") and "epoch" not in lines[1]  # a bare state dict has none
    assert lines[2] == "  kind: cylinder3d (semantics only)" and "  dropped buffers: none" in lines
    assert lines[-1].startswith(
        "semantics only: train the instance head with dsnet train dsnet DATA --init-from"
    )


@pytest.mark.parametrize(
    ("body", "problem"),
    [
        (
            b"epoch 5, PQ 0.577\n",
            "not a torch checkpoint: neither torch.save's zip archive nor its legacy pickle",
        ),
        (np.random.default_rng(1).bytes(2048), "not a torch checkpoint: neither torch.save's zip archive"),
    ],
)
def test_a_file_torch_did_not_write_is_one_typed_line(tmp_path, body, problem):
    """#27: a text file ended in ``KeyError: 101``, random bytes in "arbitrary Python objects"."""
    (tmp_path / "weights.pth").write_bytes(body)
    res = CliRunner().invoke(
        app,
        ["import-checkpoint", str(tmp_path / "weights.pth"), "--out", str(tmp_path / "o"), "--kind", "dsnet"],
    )
    assert res.exit_code == 2 and res.output.startswith(f"error: {tmp_path / 'weights.pth'}: {problem}")
    assert len(res.output.strip().splitlines()) == 1 and not (tmp_path / "o").exists()


def test_non_finite_weights_are_refused(tmp_path):
    """#27: a file whose tensors were all NaN imported with exit 0."""
    state = spconv1_state(randomize(DSNetReference(4), seed=2).state_dict())
    state = {k: torch.full_like(v, float("nan")) if v.is_floating_point() else v for k, v in state.items()}
    torch.save({"epoch": 1, "model_state": state}, tmp_path / "nan.pth")
    res = CliRunner().invoke(
        app, ["import-checkpoint", str(tmp_path / "nan.pth"), "--out", str(tmp_path / "o"), "--kind", "dsnet"]
    )
    assert res.exit_code == 2, res.output
    assert res.output.startswith(
        f"error: {tmp_path / 'nan.pth'}: NaN or infinite weights in keys (286): fea_compression.0.weight, "
        "fea_compression.0.bias, backbone.downCntx.conv1.weight,"
    )
    assert not (tmp_path / "o").exists()


@pytest.mark.slow  # two label runs through a Prefect server (minutes on a shared machine)
def test_label_with_an_imported_model_then_relabel_with_another(prefect_api_url, reference_file, tmp_path):
    from flows.label import label_dataset
    from storage.run import RunStore

    runner = CliRunner()
    for name, src in (("a", reference_file), ("b", tmp_path / "b.pth")):
        if name == "b":
            state = spconv1_state(randomize(DSNetReference(4), seed=1).state_dict())
            torch.save({"epoch": 1, "model_state": state}, src)
        out = runner.invoke(
            app, ["import-checkpoint", str(src), "--out", str(tmp_path / name), "--kind", "dsnet"]
        )
        assert out.exit_code == 0, out.output
    log = write_tiny_log(tmp_path / "log", frames=2)
    shift = {"kind": "dynamic_shift", "n_seeds": 200}

    def run(ckpt):
        stages = {
            "align": {"scans": 1},
            "infer": {"checkpoint": str(tmp_path / ckpt)},
            "shift": {"clusterer": shift},
        }
        return {
            r["stage"]: r["action"] for r in label_dataset(req(str(log), str(tmp_path / "run"), None, stages))
        }

    assert set(run("a").values()) == {"fresh"}
    labels = RunStore(tmp_path / "run").arrays("00", _labels()).read_item(0)["label"]
    assert labels.shape[0] > 0 and np.all((labels & 0xFFFF) < 260)
    assert run("b") == {
        "ingest": "skip",
        "align": "skip",
        "infer": "fresh",
        "shift": "fresh",
        "fuse": "fresh",
        "track": "fresh",  # k = 1 labels with tracking by default
        "refine": "fresh",  # then refines them (on by default)
        "score": "fresh",
    }


@pytest.mark.slow  # a full-width forward is ~20 s per 3000-point scan on one CPU core
@pytest.mark.parametrize(("kind", "scans"), [("dsnet", 1), ("dsnet4d", 2)])
def test_a_file_in_the_layout_the_reference_saves_imports_and_labels_a_log(
    prefect_api_url, tmp_path, kind, scans
):
    """Random tensors of the recorded keys and shapes at the released width (INIT_SIZE 32), in
    the reference's checkpoint dict: imported through the command, then labelling a small log."""
    from flows.label import label_dataset
    from storage.run import RunStore

    src = save_wrapped(random_state(kind, seed=3), tmp_path / f"{kind}.pth")
    res = CliRunner().invoke(
        app, ["import-checkpoint", str(src), "--out", str(tmp_path / "ckpt"), "--kind", kind]
    )
    assert res.exit_code == 0, res.output
    assert f"  kind: {kind}\n  width: 32 (20 classes)\n" in res.output
    assert "  dropped buffers: sem_loss.weight (20,)" in res.output
    log = write_tiny_log(tmp_path / "log", frames=2, n=600)
    stages = {
        "align": {"scans": scans},
        "infer": {"checkpoint": str(tmp_path / "ckpt")},
        "shift": {"clusterer": {"kind": "dynamic_shift", "n_seeds": 100}},
    }
    done = label_dataset(req(str(log), str(tmp_path / "run"), None, stages))
    temporal = "track" if scans == 1 else "stitch"  # k = 1 tracks, 4D-DS-Net (k = 2) stitches volumes
    assert {r["stage"]: r["action"] for r in done}[temporal] == "fresh"
    assert {r["action"] for r in done} == {"fresh"}
    arrays = RunStore(tmp_path / "run").arrays("00", _labels(temporal))
    for item in range(2):
        labels = arrays.read_item(item)["label"]
        assert labels.shape[0] > 0 and np.all((labels & 0xFFFF) < 260)


def _labels(temporal: str = "track"):
    from tasks.methods import get_pipeline

    return get_pipeline("dsnet", temporal=temporal)[temporal].contract
