"""The bundled demo models: integrity, provenance, and quality on a scan no training saw."""

import pytest
import torch
from safetensors import safe_open

from dsnet_core.checkpoints import bundled_checkpoint, bundled_dir, resolve_checkpoint
from dsnet_core.instance.shifting import BANDWIDTHS_3D, BANDWIDTHS_4D
from dsnet_core.io.semantickitti import SemanticKittiReader
from dsnet_core.labels import load_label_map
from dsnet_core.model.bundle import load_shift_weights
from dsnet_core.model.checkpoint import load_checkpoint, read_card
from dsnet_core.model.inference import Predictor
from dsnet_core.synth import generate_log
from dsnet_core.train.metrics import ConfusionMeter

LM = load_label_map("semantic-kitti")
# on the held-out scan below (a crossroads seen by a VLP-32C: a style and a sensor training never
# drew) tiny-v2 measured mIoU 0.355 and its predecessor tiny 0.120; random weights give ~0.02
MIOU_FLOOR = 0.3


HELD_OUT_STYLES = {"junction", "parking_lot"}  # bench/bench_transfer.py's held-out cells
HELD_OUT_SENSORS = {"vlp32", "nuscenes32"}


def test_the_bundle_picks_the_model_by_k():
    assert bundled_checkpoint(1) == bundled_dir(1) and bundled_dir(1).name == "tiny-v2"
    for k in (2, 3, 4):
        assert bundled_checkpoint(k) == bundled_dir(2) and bundled_dir(k).name == "tiny-v2-4d"
    assert resolve_checkpoint(None, 1) == bundled_dir(1) and resolve_checkpoint(None, 3) == bundled_dir(2)


def test_bundled_models_are_complete_and_the_4d_one_derives_from_the_3d_one():
    v2, card = load_checkpoint(bundled_dir(1), expect_label_map=LM)  # verifies the weights' sha256
    v2_4d, card4d = load_checkpoint(bundled_dir(2), expect_label_map=LM)
    assert card.epochs == {"semantic": 8, "offset": 3, "shift": 2}
    assert card4d.epochs == {"joint": 2, "shift": 1}
    assert card.training_data["scans"] == 1 and card4d.training_data["scans"] == 2
    for c in (card, card4d):  # trained on the stream, never on the transfer bench's held-out cells
        stream = c.training_data["stream"]
        assert not HELD_OUT_STYLES & set(stream["styles"]) and not HELD_OUT_SENSORS & set(stream["sensors"])
    # tiny-v2 started from the first bundled model; the 4D model from tiny-v2's semantic stage
    first = read_card(bundled_dir(1).parent / "tiny")
    assert card.training_data["init_from"]["weights_sha256"] == first.weights_sha256
    assert card4d.training_data["init_from"]["epochs"] == {"semantic": card.epochs["semantic"]}
    # the joint stage trained the backbone on 2-scan volumes: k > 1 has semantics of its own
    a, b = v2.state_dict(), v2_4d.state_dict()
    assert any(not torch.equal(a[k], b[k]) for k in a if k.startswith("backbone."))
    for path, bandwidths in ((bundled_dir(1), BANDWIDTHS_3D), (bundled_dir(2), BANDWIDTHS_4D)):
        weights = load_shift_weights(path)
        assert weights is not None and weights["mlps.0.0.weight"].shape == (32, 32)
        with safe_open(str(path / "shift.safetensors"), "pt") as f:
            assert f.metadata()["bandwidths"] == ",".join(str(b) for b in bandwidths)


def test_the_first_bundled_models_are_kept_and_verify():
    """``tiny`` and ``tiny-4d`` stay in the package (the MOST and D-PLS models started from ``tiny``)."""
    models = bundled_dir(1).parent
    tiny, card = load_checkpoint(models / "tiny", expect_label_map=LM)
    tiny4d, card4d = load_checkpoint(models / "tiny-4d", expect_label_map=LM)
    assert card.epochs == {"semantic": 22, "offset": 6, "shift": 3} and card4d.epochs == {
        "offset": 3,
        "shift": 2,
    }
    a, b = tiny.state_dict(), tiny4d.state_dict()  # tiny-4d trained only the instance head
    assert all(torch.equal(a[k], b[k]) for k in a if not k.startswith("ins_head."))


@pytest.fixture(scope="module")
def held_out_scan(tmp_path_factory):
    root = tmp_path_factory.mktemp("held_out")
    generate_log(root, sequences=1, frames=1, seed=4242, sensor="vlp32", style="junction", first_sequence=90)
    reader = SemanticKittiReader(root)
    frame = reader.frames("90")[0]
    return reader.scan(frame), LM.to_train(reader.labels(frame) & 0xFFFF)


def test_bundled_model_segments_a_scan_no_training_saw(held_out_scan):
    torch.set_num_threads(1)
    points, truth = held_out_scan
    scores = {}
    for path in (bundled_dir(1), bundled_dir(1).parent / "tiny"):
        res = Predictor.from_checkpoint(path, expect_label_map=LM).predict(points)
        meter = ConfusionMeter(LM.num_classes)
        meter.add(res.sem, truth)
        scores[path.name] = meter.miou()
    assert scores["tiny-v2"] > MIOU_FLOOR
    assert scores["tiny-v2"] > scores["tiny"] + 0.1  # the diverse stream transfers; one street style did not
    assert res.offsets.shape == (len(points), 3) and res.features.shape == (len(points), 32)


def test_scaled_shift_weights_are_refused_naming_the_file(tmp_path):
    from safetensors.torch import save_file

    from dsnet_core.errors import CheckpointError
    from dsnet_core.model.checkpoint import read_card
    from tests.model_helpers import make_checkpoint

    ckpt = make_checkpoint(tmp_path / "ckpt")
    good = load_shift_weights(ckpt)
    assert read_card(ckpt).shift_sha256 and good is not None
    save_file({k: 2 * v for k, v in good.items()}, str(ckpt / "shift.safetensors"))  # scaled in place
    with pytest.raises(CheckpointError, match=r"ckpt/shift\.safetensors: shifting weights do not match"):
        load_shift_weights(ckpt)
    (ckpt / "shift.safetensors").write_bytes(b"")  # truncated
    with pytest.raises(CheckpointError, match=r"shift\.safetensors: shifting weights do not match"):
        load_shift_weights(ckpt)


def test_lost_shift_weights_recorded_by_the_card_are_refused(tmp_path):
    """A deleted shift.safetensors whose sha256 the card records made the shift stage fall back
    to fixed weights with a log warning: other instance labels, exit 0."""
    from dsnet_core.errors import CheckpointError
    from tests.model_helpers import make_checkpoint

    ckpt = make_checkpoint(tmp_path / "ckpt")
    (ckpt / "shift.safetensors").unlink()
    with pytest.raises(CheckpointError, match=r"shift\.safetensors: shifting weights are missing"):
        load_shift_weights(ckpt)
    assert load_shift_weights(make_checkpoint(tmp_path / "plain", shift_weights=False)) is None


def test_every_bundled_model_verifies_against_its_card():
    """Each folder under data/models loads through its method's loader, which checks the weights'
    sha256 against the card (a DS-Net, D-PLS or MOST checkpoint alike)."""
    from dsnet_core.checkpoints import MOST, bundled_dir, checkpoint_method
    from dsnet_core.model.checkpoint import load_checkpoint
    from dsnet_core.most.checkpoint import load_most_checkpoint

    folders = sorted(p for p in bundled_dir(1).parent.iterdir() if (p / "card.json").is_file())
    assert {p.name for p in folders} >= {"tiny-v2", "tiny-v2-4d", "tiny", "tiny-4d", "dpls", "most"}
    for path in folders:
        loader = load_most_checkpoint if checkpoint_method(path) == "most" else load_checkpoint
        _, card = loader(path)
        assert card.epochs, path
    assert MOST.bundled(1) == MOST.bundled(3)  # one MOST model serves every k
