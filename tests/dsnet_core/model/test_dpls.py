"""D-PLS's instance network: the prior widens the point input, the copy of a DS-Net starts with its
exact offsets, and the prior is really used (another prior, other offsets)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from dsnet_core.errors import CheckpointError, ConfigError
from dsnet_core.model.dpls import BASE_FEATURES, DplsPredictor, dpls_config, init_from_semantic, one_hot
from dsnet_core.model.network import DSNet
from tests.model_helpers import TEST_CONFIG, make_checkpoint


def _cloud(n: int = 3000, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    pts = rng.uniform([-30, -30, -2, 0], [30, 30, 1, 1], size=(n, 4)).astype(np.float32)
    return pts


def test_the_input_width_includes_the_prior_and_a_copy_starts_as_its_parent():
    torch.manual_seed(0)
    parent = DSNet(TEST_CONFIG).eval()
    net = DSNet(dpls_config(TEST_CONFIG)).eval()
    assert net.sem_head is None and net.config.prior_channels == TEST_CONFIG.num_classes == 20
    assert net.point_encoder.mlp[1].in_features == BASE_FEATURES + 20
    assert init_from_semantic(net, parent) == []
    pts = torch.from_numpy(_cloud())
    with torch.no_grad():
        a = parent([pts]).offsets
        b = net([pts], priors=[one_hot(np.full(len(pts), 1), 20)]).offsets
        c = net([pts], priors=[one_hot(np.full(len(pts), 13), 20)]).offsets
    assert torch.equal(a, b) and torch.equal(b, c)  # the prior's columns start at zero
    with pytest.raises(ConfigError, match="needs one"):
        net([pts])


def test_the_trained_network_uses_its_prior(synth_log):
    """The bundled D-PLS model: the same points with their cars' prior turned into road move their
    offsets (a random-weight network is too flat to show it); an unchanged prior repeats exactly."""
    from dsnet_core.checkpoints import DPLS
    from dsnet_core.io.semantickitti import SemanticKittiReader
    from dsnet_core.labels import load_label_map

    lm = load_label_map("semantic-kitti")
    pred = DplsPredictor.from_checkpoint(DPLS.bundled())
    reader = SemanticKittiReader(synth_log)
    ref = reader.frames("00")[0]
    pts = reader.scan(ref)
    sem = lm.to_train(reader.labels(ref) & 0xFFFF)
    car = sem == 1
    assert car.sum() > 100
    off_a, feat_a = pred.predict(pts, sem)
    off_b, _ = pred.predict(pts, np.where(car, 9, sem))
    assert np.array_equal(off_a, pred.predict(pts, sem)[0])
    assert off_a.shape == (len(pts), 3) and feat_a.shape == (len(pts), 32) and feat_a.dtype == np.float16
    moved = np.linalg.norm(off_a[car] - off_b[car], axis=1)
    # measured 0.026 m median, 0.5 m at the 99th percentile: a short CPU fine-tune moves the prior's
    # columns off zero only a little (docs/dpls.md); float noise alone would be ~1e-6 m
    assert np.median(moved) > 0.01 and np.percentile(moved, 99) > 0.1, np.percentile(moved, [50, 99])


def test_a_plain_dsnet_checkpoint_is_not_a_dpls_one(tmp_path):
    with pytest.raises(CheckpointError, match="without a semantic-prior input: label with --method dsnet"):
        DplsPredictor.from_checkpoint(make_checkpoint(tmp_path / "c"))


def test_the_bundled_dpls_model_derives_from_tiny_and_the_bundle_stays_under_its_cap():
    from pathlib import Path

    from dsnet_core.checkpoints import DPLS, bundled_dir
    from dsnet_core.labels import load_label_map
    from dsnet_core.model.checkpoint import load_checkpoint, read_card
    from dsnet_core.model.dpls import is_dpls

    path = DPLS.bundled()
    assert path is not None and DPLS.resolve(None) == path
    model, card = load_checkpoint(path, expect_label_map=load_label_map("semantic-kitti"))
    assert is_dpls(model.config) and card.epochs["dpls"] >= 1
    models = Path(bundled_dir(1)).parent
    # trained from the first bundled DS-Net model, kept in the package as its provenance
    assert card.training_data["init_from"]["weights_sha256"] == read_card(models / "tiny").weights_sha256
    assert len(card.training_data["prior_noise"]["confusion"]) == 20
    total = sum(f.stat().st_size for f in models.rglob("*.safetensors"))
    assert total < 40e6, f"bundled weights take {total / 1e6:.1f} MB, over the 40 MB cap"
