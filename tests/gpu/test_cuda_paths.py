"""Every model path on CUDA equals the CPU path within stated tolerances (marker ``gpu``, run by
``make test-gpu`` on a machine with a CUDA device; deselected from ``make test``).

Tolerances: the network's logits and offsets to 1e-3 (float32 GEMM order and TF32 differ between
the devices; argmax labels may flip only where two classes tie to that precision), one training
step's loss to 1e-3 relative, dynamic shifting's targets to 1e-5 (test_shifting.py).
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from dsnet_core.io.semantickitti import SemanticKittiReader
from dsnet_core.model.inference import Predictor
from tests.dsnet_core.train.test_loop import trainer
from tests.helpers.tiny_log import write_tiny_log
from tests.model_helpers import make_checkpoint

pytestmark = [
    pytest.mark.gpu,
    pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device"),
]


@pytest.fixture(scope="module")
def log(tmp_path_factory):
    return write_tiny_log(tmp_path_factory.mktemp("log"), frames=3)


def test_inference_on_cuda_equals_cpu(log, tmp_path):
    torch.backends.cuda.matmul.allow_tf32 = False
    ckpt = make_checkpoint(tmp_path / "ckpt", seed=0)
    reader = SemanticKittiReader(log)
    scan = reader.scan(reader.frames("00")[0])
    cpu = Predictor.from_checkpoint(ckpt, device="cpu").predict(scan)
    gpu = Predictor.from_checkpoint(ckpt, device="cuda").predict(scan)
    np.testing.assert_allclose(gpu.probs.astype(np.float32), cpu.probs.astype(np.float32), atol=1e-3)
    np.testing.assert_allclose(gpu.offsets, cpu.offsets, atol=1e-3)
    assert (gpu.sem == cpu.sem).mean() > 0.999


@pytest.mark.parametrize("amp", ["off", "bf16", "fp16"])
def test_training_on_cuda_follows_cpu(log, tmp_path, amp):
    kw = dict(stage="all", epochs={"semantic": 1, "offset": 1, "shift": 1})
    cpu = trainer(log, tmp_path / "cpu", **kw).run()
    gpu = trainer(log, tmp_path / "gpu", device="cuda", amp=amp, **kw).run()
    assert gpu.training_data["train_config"]["amp"] == amp
    tol = 1e-3 if amp == "off" else 0.05  # half precision rounds the forward pass
    for a, b in zip(cpu.metrics, gpu.metrics, strict=True):
        assert abs(a["train_loss"] - b["train_loss"]) <= tol * abs(a["train_loss"]), (a, b)
