"""Test-time augmentation: identity for one pass, exact inverse transforms, and invariance of the
averaged semantics (equivariance of the averaged offsets) under a rotation in the averaged set."""

import math

import numpy as np
import pytest
import torch

from dsnet_core.errors import ConfigError
from dsnet_core.model.inference import Predictor
from dsnet_core.model.network import DSNet
from dsnet_core.model.tta import TTAConfig, transform_points, tta_forward, untransform_vectors
from tests.dsnet_core.model.rotation_helpers import (
    CFG,
    away_from_cell_boundaries,
    calibrated,
    rotate64,
    rotate_vectors,
)


@pytest.fixture(autouse=True, scope="module")
def one_thread():
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture(scope="module")
def net():
    torch.manual_seed(0)
    return calibrated(DSNet(CFG), [torch.from_numpy(away_from_cell_boundaries(1000, seed=0))])


def test_config_validation():
    with pytest.raises(ConfigError, match="positive number of rotations"):
        TTAConfig(rotations=0)
    assert TTAConfig(4, flip=True).passes == 8
    assert TTAConfig(4, flip=True).transforms()[0] == (0.0, False)


def test_one_pass_is_the_plain_forward(net):
    pts = away_from_cell_boundaries(500, seed=1)
    plain = Predictor(net, threads=None).predict(pts)
    tta = Predictor(net, threads=None, tta=TTAConfig(1)).predict(pts)
    for a, b in zip(
        (plain.sem, plain.probs, plain.offsets, plain.features),
        (tta.sem, tta.probs, tta.offsets, tta.features),
        strict=True,
    ):
        assert np.array_equal(a, b)


@pytest.mark.parametrize("angle,mirrored", [(0.7, False), (2.1, True), (0.0, True)])
def test_vectors_go_back_to_the_input_frame(angle, mirrored):
    g = torch.Generator().manual_seed(0)
    v = torch.randn(50, 4, generator=g, dtype=torch.float64)
    back = untransform_vectors(transform_points(v, angle, mirrored)[:, :3], angle, mirrored)
    torch.testing.assert_close(back, v[:, :3], rtol=0, atol=1e-12)
    # a transformed point plus its transformed offset is the transformed target
    p, o = v[:10, :3], v[10:20, :3]
    tp = transform_points(torch.cat([p, torch.zeros(10, 1, dtype=p.dtype)], 1), angle, mirrored)[:, :3]
    tt = transform_points(torch.cat([p + o, torch.zeros(10, 1, dtype=p.dtype)], 1), angle, mirrored)[:, :3]
    torch.testing.assert_close(untransform_vectors(tt - tp, angle, mirrored), o, rtol=0, atol=1e-12)


@pytest.mark.parametrize("flip", [False, True])
def test_averaged_outputs_follow_a_rotation_of_the_set(net, flip):
    """TTA over N rotations of 2π/N (each an exact shift of the 36 azimuth cells for N = 4) is
    invariant to rotating the input by 2π/N: the same passes in another order."""
    cfg = TTAConfig(4, flip=flip)
    pts = away_from_cell_boundaries(800, seed=2)
    angle = 2 * math.pi / 4
    with torch.inference_mode():
        a = tta_forward(net, [torch.from_numpy(pts)], cfg)
        b = tta_forward(net, [torch.from_numpy(rotate64(pts, angle))], cfg)
    torch.testing.assert_close(b.logits, a.logits, rtol=1e-4, atol=1e-5)
    torch.testing.assert_close(b.offsets, rotate_vectors(a.offsets, angle), rtol=1e-4, atol=1e-5)
    # and it differs from the plain pass (the averaging happened)
    with torch.inference_mode():
        plain = net([torch.from_numpy(pts)])
    assert not torch.allclose(plain.logits, a.logits, atol=1e-3)
