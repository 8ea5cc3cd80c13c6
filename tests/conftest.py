"""Session-wide test setup and shared fixtures.

Prefect runs with a temporary home, analytics and API logging off.
"""

import atexit
import os
import shutil
import tempfile
from pathlib import Path

import pytest

_PREFECT_HOME = tempfile.mkdtemp(prefix="dsnet-test-prefect-")
os.environ["PREFECT_HOME"] = _PREFECT_HOME
os.environ.pop("PREFECT_API_URL", None)
os.environ.setdefault("PREFECT_SERVER_ANALYTICS_ENABLED", "false")
os.environ.setdefault("PREFECT_LOGGING_TO_API_ENABLED", "false")
os.environ.setdefault("PREFECT_SERVER_UI_ENABLED", "false")
atexit.register(shutil.rmtree, _PREFECT_HOME, ignore_errors=True)


@pytest.fixture(scope="session")
def synth_log(tmp_path_factory) -> Path:
    """A small synthetic log (VLP-32-like, sequences "00" and "01" × 6 frames, seed 0) in the
    SemanticKITTI layout, with labels, poses, calib and times. Treat it as read-only."""
    from dsnet_core.synth import generate_log

    root = tmp_path_factory.mktemp("synth_log")
    generate_log(root, sequences=2, frames=6, seed=0, sensor="vlp32")
    return root
