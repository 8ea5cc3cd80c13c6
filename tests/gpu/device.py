"""The device the ``gpu`` tests run their CUDA side on.

CUDA where torch sees one. Without CUDA, ``DSNET_GPU_TESTS_ON_CPU=1`` (set by
``gpu/gpu_check.py --device cpu``) runs the same tests with the CPU on both sides: a smoke run
proving the tests and their imports work on a machine with only the GPU machine's packages, not
that CUDA equals CPU. Otherwise the tests are skipped.
"""

from __future__ import annotations

import os

import pytest
import torch

ON_CPU = "DSNET_GPU_TESTS_ON_CPU"


def gpu_device() -> str | None:
    """``"cuda"``, ``"cpu"`` (smoke run, see the module's docstring) or None (skip)."""
    if torch.cuda.is_available():
        return "cuda"
    return "cpu" if os.environ.get(ON_CPU) == "1" else None


DEVICE = gpu_device()
SMOKE = DEVICE == "cpu"
MARKS = [pytest.mark.gpu, pytest.mark.skipif(DEVICE is None, reason="needs a CUDA device")]
