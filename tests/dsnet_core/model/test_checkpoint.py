import json
import math

import numpy as np
import pytest
import torch

from dsnet_core.labels import load_label_map
from dsnet_core.model.card import card_text
from dsnet_core.model.checkpoint import (
    CheckpointError,
    CheckpointMismatchError,
    ModelCard,
    class_map_of,
    load_checkpoint,
    read_card,
    save_checkpoint,
)
from dsnet_core.model.cylinder import CylinderGrid
from dsnet_core.model.inference import Predictor
from dsnet_core.model.network import DSNet
from dsnet_core.model.presets import ModelConfig
from dsnet_core.model.tta import TTAConfig

GRID = CylinderGrid(size=(24, 20, 8), min_bound=(0.0, -math.pi, -2.0), max_bound=(12.0, math.pi, 1.0))
CFG = ModelConfig(width=2, point_mlp=(8, 8), compress=4, ins_dim=6, grid=GRID)


@pytest.fixture
def ckpt(tmp_path):
    torch.manual_seed(0)
    model = DSNet(CFG)
    card = ModelCard(
        architecture={},
        class_map=class_map_of(load_label_map("semantic-kitti")),
        training_data={"fingerprint": "abc"},
        epochs={"semantic": 2},
        metrics=[{"epoch": 1, "miou": 0.5}],
    )
    return save_checkpoint(tmp_path / "ckpt", model, card), model


def cloud(n=300, seed=0):
    rng = np.random.default_rng(seed)
    return (rng.normal(size=(n, 4)) * 4).astype(np.float32)


def test_round_trip_weights_and_card(ckpt):
    path, model = ckpt
    loaded, card = load_checkpoint(path, expect_config=CFG, expect_label_map=load_label_map("semantic-kitti"))
    for (k, a), (_, b) in zip(model.state_dict().items(), loaded.state_dict().items(), strict=True):
        assert torch.equal(a, b), k
    assert (
        card.config == CFG and card.epochs == {"semantic": 2} and card.training_data["fingerprint"] == "abc"
    )
    assert card.code_version and len(card.weights_sha256) == 64
    assert json.loads((path / "card.json").read_text())["class_map"]["class_names"][1] == "car"


def test_tampered_weights_fail(ckpt):
    path, _ = ckpt
    raw = bytearray((path / "model.safetensors").read_bytes())
    raw[-5] ^= 0xFF
    (path / "model.safetensors").write_bytes(bytes(raw))
    with pytest.raises(CheckpointError, match="do not match the model card's sha256"):
        load_checkpoint(path)


def test_tampered_card_fails(ckpt):
    path, _ = ckpt
    (path / "card.json").write_text("{not json")
    with pytest.raises(CheckpointError, match="not valid JSON"):
        read_card(path)
    with pytest.raises(CheckpointError, match="no model card"):
        load_checkpoint(path.parent / "nowhere")


def test_mismatched_architecture_and_class_map(ckpt):
    path, _ = ckpt
    with pytest.raises(CheckpointMismatchError, match="width: expected 4, checkpoint has 2"):
        load_checkpoint(
            path, expect_config=ModelConfig(width=4, point_mlp=(8, 8), compress=4, ins_dim=6, grid=GRID)
        )
    with pytest.raises(CheckpointMismatchError, match="class map differs"):
        load_checkpoint(path, expect_label_map=load_label_map("panoptic-nuscenes"))


def test_card_architecture_edited_to_another_shape_fails(ckpt):
    # an attacker (or a bad merge) edits the card's width: the weights no longer fit
    path, _ = ckpt
    data = json.loads((path / "card.json").read_text())
    data["architecture"]["width"] = 3
    (path / "card.json").write_text(card_text(data))
    with pytest.raises(CheckpointMismatchError, match="do not fit the card's architecture"):
        load_checkpoint(path)


def test_predictor_outputs(ckpt):
    path, model = ckpt
    pred = Predictor.from_checkpoint(path, device="cpu")
    assert torch.get_num_threads() == 1
    a, b = cloud(300, 0), cloud(120, 1)
    res = pred.predict(a)
    assert res.sem.dtype == np.int64 and res.sem.shape == (300,) and res.sem.min() >= 1
    assert res.probs.dtype == np.float16 and res.probs.shape == (300, 20)
    np.testing.assert_allclose(res.probs.astype(np.float32).sum(1), 1.0, atol=1e-2)
    assert res.offsets.dtype == np.float32 and res.offsets.shape == (300, 3)
    assert res.features.dtype == np.float16 and res.features.shape == (300, 6)
    # batched = one by one; empty clouds allowed
    batch = pred.predict_batch([a, np.zeros((0, 4), np.float32), b])
    assert batch[1].sem.shape == (0,) and batch[1].probs.shape == (0, 20)
    np.testing.assert_array_equal(batch[0].sem, res.sem)
    np.testing.assert_allclose(batch[2].offsets, pred.predict(b).offsets, atol=1e-4)
    # same numbers as the model it was saved from
    with torch.inference_mode():
        ref = model.eval()([torch.from_numpy(a)])
    np.testing.assert_allclose(res.offsets, ref.offsets.numpy(), atol=1e-5)
    # softmax and argmax taken per voxel equal them taken per point on the points' logits
    logits = ref.logits.float()
    np.testing.assert_array_equal(res.probs, torch.softmax(logits, 1).to(torch.float16).numpy())
    np.testing.assert_array_equal(res.sem, (logits[:, 1:].argmax(1) + 1).numpy())
    assert np.unique(ref.point_to_voxel.numpy()).size < 300  # some voxels hold several points


@pytest.mark.parametrize("tta", [None, TTAConfig(rotations=2)])
def test_stored_predictions_are_the_quantised_and_masked_predictions(ckpt, tta):
    """predict_stored quantises once per voxel (or per point under TTA) and converts only the kept
    points: bit for bit what quantising and masking predict_batch's results gives."""
    from tasks.infer import quantise_probs, thing_only

    path, _ = ckpt
    pred = Predictor.from_checkpoint(path, tta=tta)
    clouds = [cloud(300, 0), np.zeros((0, 4), np.float32), cloud(120, 1)]
    keep = np.zeros(20, bool)
    keep[1:9] = True
    full = pred.predict_batch(clouds)
    stored = pred.predict_stored(clouds, keep)
    assert list(pred.predict_stored_iter(clouds, keep, batch_size=2))[2].probs.shape == (120, 20)
    for f, s in zip(full, stored, strict=True):
        kept = keep[f.sem]
        assert np.array_equal(s.kept, kept) and np.array_equal(s.sem, f.sem)
        assert s.probs.dtype == np.uint8 and np.array_equal(s.probs, quantise_probs(f.probs))
        for got, want, dtype in ((s.offsets, f.offsets, "float32"), (s.features, f.features, "float16")):
            assert got.dtype == np.dtype(dtype) and np.array_equal(got, thing_only(want, kept, dtype))
    assert 0 < stored[0].kept.sum() < 300  # some points kept, some not


def test_predictor_rejects_bad_points(ckpt):
    path, _ = ckpt
    pred = Predictor.from_checkpoint(path)
    bad = cloud(10)
    bad[3, 1] = np.nan
    with pytest.raises(Exception, match=r"finite float \(N, 4\)"):
        pred.predict(bad)


def test_card_with_a_malformed_class_map_or_architecture_names_the_card(ckpt):
    """A flipped bit in the card's class map ("1" -> ")") was found only by the infer stage, as a
    ConfigError naming no file ("model card class map is incomplete or malformed")."""
    path, _ = ckpt
    good = json.loads((path / "card.json").read_text())
    data = json.loads(json.dumps(good))
    key = next(iter(data["class_map"]["learning_map_inv"]))
    data["class_map"]["learning_map_inv"][")"] = data["class_map"]["learning_map_inv"].pop(key)
    (path / "card.json").write_text(card_text(data))
    with pytest.raises(CheckpointError, match=r"card.json: model card class map is incomplete or malformed"):
        read_card(path)
    data = json.loads(json.dumps(good))
    data["architecture"]["grid"] = "not a grid"
    (path / "card.json").write_text(card_text(data))
    with pytest.raises(CheckpointError, match=r"card.json: model card architecture is malformed"):
        read_card(path)


def test_an_edit_that_still_parses_is_refused_by_the_cards_own_digest(ckpt):
    """Found by the model-folder fuzz (issue 40): a flipped bit in card.json that left valid JSON (a
    class name, a metric, the import record) was read without a word."""
    from dsnet_core.model.card import CARD_DIGEST, card_json

    path, _ = ckpt
    text = (path / "card.json").read_text()
    data = json.loads(text)
    assert len(data[CARD_DIGEST]) == 64
    assert CARD_DIGEST not in card_json(path)  # the reader hands out the card without it
    (path / "card.json").write_text(text.replace('"miou": 0.5', '"miou": 0.7'))
    with pytest.raises(CheckpointError, match=r"card\.json: model card does not match its own sha256") as err:
        read_card(path)
    assert f'delete its "{CARD_DIGEST}" entry' in str(err.value) and "\n" not in str(err.value)
    data.pop(CARD_DIGEST)  # a card written before the digest existed (the bundled ones) reads as it is
    data["metrics"][0]["miou"] = 0.7
    (path / "card.json").write_text(json.dumps(data))
    assert read_card(path).metrics[0]["miou"] == 0.7
