"""``dsnet import-checkpoint`` on a reconstructed reference file, then ``dsnet label`` with the
imported model; relabelling with another checkpoint recomputes infer onward only."""

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from dsnet_core.model.checkpoint import read_card
from flows.cli import app
from tests.dsnet_core.model.reference_net import DSNetReference, randomize, spconv1_state
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
    assert "spconv1 layout, spconv1-shared rulebooks" in res.output and "4 shifting iterations" in res.output
    assert read_card(tmp_path / "ckpt").training_data["imported"]["kind"] == "dsnet"
    bad = CliRunner().invoke(
        app, ["import-checkpoint", str(reference_file), "--out", str(tmp_path / "x"), "--kind", "cylinder3d"]
    )
    assert bad.exit_code == 2 and "error:" in bad.output and "unknown keys" in bad.output


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
    labels = RunStore(tmp_path / "run").arrays("00", _track()).read_item(0)["label"]
    assert labels.shape[0] > 0 and np.all((labels & 0xFFFF) < 260)
    assert run("b") == {
        "ingest": "skip",
        "align": "skip",
        "infer": "fresh",
        "shift": "fresh",
        "fuse": "fresh",
        "track": "fresh",  # k = 1 labels with tracking by default
        "score": "fresh",
    }


def _track():
    from tasks.methods import get_pipeline

    return get_pipeline("dsnet", temporal="track")["track"].contract
