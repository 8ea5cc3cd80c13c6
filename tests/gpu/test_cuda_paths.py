"""The network and the trainer on CUDA equal the CPU path within stated tolerances (marker ``gpu``,
run by ``make test-gpu`` and ``make gpu-check`` on a machine with a CUDA device; deselected from
``make test``; see tests/gpu/device.py for the CPU smoke run).

Tolerances: the network's probabilities and offsets to 1e-3 (float32 GEMM order and TF32 differ
between the devices; labels may flip only where two classes tie to that precision, so at least
99.9 % must agree), a training epoch's loss to 1e-3 relative without AMP and 5 % with it (half
precision rounds the forward pass).
"""

from __future__ import annotations

import numpy as np
import pytest

from dsnet_core.io.semantickitti import SemanticKittiReader
from dsnet_core.model.inference import Predictor
from tests.dsnet_core.train.test_loop import trainer
from tests.gpu.device import DEVICE, MARKS, SMOKE
from tests.helpers.tiny_log import write_tiny_log
from tests.model_helpers import make_checkpoint

pytestmark = MARKS


@pytest.fixture(scope="module")
def log(tmp_path_factory):
    return write_tiny_log(tmp_path_factory.mktemp("log"), frames=3)


@pytest.mark.parametrize("scans", [1, 2])
def test_inference_on_cuda_equals_cpu(log, tmp_path, scans):
    """A single scan and a two-scan volume (two frames concatenated, as align writes them)."""
    ckpt = make_checkpoint(tmp_path / "ckpt", seed=0)
    reader = SemanticKittiReader(log)
    cloud = np.concatenate([reader.scan(f) for f in reader.frames("00")[:scans]])
    cpu = Predictor.from_checkpoint(ckpt, device="cpu").predict(cloud)
    gpu = Predictor.from_checkpoint(ckpt, device=DEVICE).predict(cloud)
    np.testing.assert_allclose(gpu.probs.astype(np.float32), cpu.probs.astype(np.float32), atol=1e-3)
    np.testing.assert_allclose(gpu.offsets, cpu.offsets, atol=1e-3)
    np.testing.assert_allclose(gpu.features.astype(np.float32), cpu.features.astype(np.float32), atol=2e-3)
    assert (gpu.sem == cpu.sem).mean() > 0.999


@pytest.mark.parametrize("amp", ["off", "bf16", "fp16"])
def test_training_on_cuda_follows_cpu(log, tmp_path, amp):
    """Every stage (semantic, instance head, shifting) at batch 2, in each AMP mode, against the
    CPU's float32 run of the same seed."""
    if SMOKE and amp == "fp16":
        pytest.skip("fp16 AMP (with its gradient scaler) is CUDA-only")
    kw = dict(stage="all", epochs={"semantic": 1, "offset": 1, "shift": 1}, batch_size=2)
    cpu = trainer(log, tmp_path / "cpu", **kw).run()
    gpu = trainer(log, tmp_path / "gpu", device=DEVICE, amp=amp, **kw).run()
    assert gpu.training_data["train_config"]["amp"] == amp
    assert [m["stage"] for m in gpu.metrics] == ["semantic", "offset", "shift"]
    tol = 1e-3 if amp == "off" else 0.05
    for a, b in zip(cpu.metrics, gpu.metrics, strict=True):
        assert abs(a["train_loss"] - b["train_loss"]) <= tol * abs(a["train_loss"]), (a, b)
