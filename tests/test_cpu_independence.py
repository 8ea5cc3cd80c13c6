"""Results pinned in tests do not depend on the CPU's vector instructions.

The tests that pin values by digest or compare classes run again in subprocesses that emulate
other CPUs on this one: numpy's SIMD dispatch (``NPY_DISABLE_CPU_FEATURES``, numpy ≥ 2.4 names:
the older ``AVX512F …`` names are not disabled: numpy warns and keeps its AVX-512 kernels), torch's
kernels (``ATEN_CPU_CAPABILITY``),
OpenBLAS's kernel (``OPENBLAS_CORETYPE``), numba's code generation (``NUMBA_CPU_NAME``) and MKL's
code path (``MKL_CBWR``). Each emulation is first checked to be in effect.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PINNING = (
    "tests/dsnet_core/synth/test_default_output.py",
    "tests/test_golden.py",
    "tests/dsnet_core/model/test_equivariant.py",
    "tests/dsnet_core/model/test_tta.py",
    "tests/dsnet_core/train/test_equivariant_training.py",
)
NO_AVX512 = "X86_V4 AVX512_ICL AVX512_SPR"
# name: (environment, torch's capability and numpy's widest feature group it must give)
EMULATIONS = {
    "avx2": (
        {
            "NPY_DISABLE_CPU_FEATURES": NO_AVX512,
            "ATEN_CPU_CAPABILITY": "avx2",
            "OPENBLAS_CORETYPE": "Haswell",
            "NUMBA_CPU_NAME": "haswell",
            "NUMBA_CPU_FEATURES": "+avx2,+fma",
        },
        "AVX2",
        "X86_V3",
    ),
    "no-vector": (
        {
            "NPY_DISABLE_CPU_FEATURES": f"X86_V3 {NO_AVX512}",
            "ATEN_CPU_CAPABILITY": "default",
            "OPENBLAS_CORETYPE": "Nehalem",
            "NUMBA_CPU_NAME": "generic",
            "MKL_CBWR": "COMPATIBLE",
        },
        "DEFAULT",
        "X86_V2",
    ),
    "avx512": (
        {
            "ATEN_CPU_CAPABILITY": "avx512",
            "OPENBLAS_CORETYPE": "SkylakeX",
            "NUMBA_CPU_NAME": "skylake-avx512",
            "NUMBA_CPU_FEATURES": "+avx512f,+avx512dq,+avx512bw,+avx512vl,+avx512cd",
        },
        "AVX512",
        "X86_V4",
    ),
}
PROBE = """
import numpy, torch
from numpy._core._multiarray_umath import __cpu_baseline__, __cpu_dispatch__, __cpu_features__
groups = [g for g in ("X86_V2", "X86_V3", "X86_V4") if g in __cpu_baseline__ or
          (g in __cpu_dispatch__ and __cpu_features__.get(g))]
print(torch.backends.cpu.get_cpu_capability(), groups[-1])
"""


def _has_avx512() -> bool:
    import torch

    return torch.backends.cpu.get_cpu_capability() == "AVX512"


@pytest.mark.slow
@pytest.mark.timeout(1500)
@pytest.mark.parametrize("name", sorted(EMULATIONS))
def test_pinned_results_hold_under_other_vector_instructions(name):
    settings, capability, widest = EMULATIONS[name]
    if name == "avx512" and not _has_avx512():
        pytest.skip("this CPU has no AVX-512 to select")  # its own run is the AVX2 case
    env = {**os.environ, **settings, "PYTHONPATH": str(REPO)}
    probe = subprocess.run([sys.executable, "-c", PROBE], env=env, capture_output=True, text=True)
    assert probe.returncode == 0, probe.stderr
    assert probe.stdout.split() == [capability, widest], f"{name} is not in effect: {probe.stdout}"
    cmd = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-m", "not slow", *PINNING]
    res = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True, timeout=1400)
    assert res.returncode == 0, f"under {name}:\n{res.stdout[-4000:]}"
