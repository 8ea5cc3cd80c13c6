"""The bundled C4-equivariant model (``tiny-v2-eq4``): ``dsnet label --equivariant 4`` takes it
without ``--checkpoint``, and it is equivariant as loaded (a 90° yaw rotation of the scan leaves
the classes and rotates the offsets, within float rounding)."""

from __future__ import annotations

import math

import numpy as np
import torch

from dsnet_core.checkpoints import DSNET_EQUIVARIANT
from dsnet_core.model.checkpoint import load_checkpoint
from dsnet_core.model.equivariant import rotate_xy
from tasks.methods import stage_configs
from tests.dsnet_core.model.rotation_helpers import assert_same_classes, away_from_cell_boundaries, rotate64


def test_label_equivariant_4_takes_the_bundled_model_and_it_is_equivariant():
    path = DSNET_EQUIVARIANT[4].bundled()
    assert path is not None and path.name == "tiny-v2-eq4"
    assert 8 not in DSNET_EQUIVARIANT  # none bundled: --equivariant 8 needs --checkpoint
    assert stage_configs(scans=1, equivariant=4)["infer"] == {"checkpoint": str(path), "equivariant": 4}
    model, _ = load_checkpoint(path)  # checks the weights' sha256 against the card
    assert model.config.equivariant == 4
    pts = away_from_cell_boundaries(3000, seed=5, grid=model.config.grid).astype(np.float64)
    model.eval()
    with torch.inference_mode():
        ref = model([torch.from_numpy(pts)])
        for j in (1, 2, 3):
            angle = 2 * math.pi * j / 4
            out = model([torch.from_numpy(rotate64(pts, angle, dtype=np.float64))])
            assert_same_classes(out.logits, ref.logits, atol=2.5e-4)  # classes away from near-ties
            expect = rotate_xy(ref.offsets.double(), torch.tensor(angle)).float()
            torch.testing.assert_close(out.offsets, expect, atol=1e-4, rtol=0)
