"""Shared fixtures."""

from pathlib import Path

import pytest


@pytest.fixture(scope="session")
def synth_log(tmp_path_factory) -> Path:
    """A small synthetic log (VLP-32-like, sequences "00" and "01" × 6 frames, seed 0) in the
    SemanticKITTI layout, with labels, poses, calib and times. Treat it as read-only."""
    from dsnet_core.synth import generate_log

    root = tmp_path_factory.mktemp("synth_log")
    generate_log(root, sequences=2, frames=6, seed=0, sensor="vlp32")
    return root
