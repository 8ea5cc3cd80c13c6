"""Pre-quantised copies of the session's synthetic log (3 frames of sequence 00), one per quantum."""

from __future__ import annotations

from pathlib import Path

import pytest

from dsnet_core.io.semantickitti import SemanticKittiReader
from tests.dsnet_core.io.encode import quantised_log

FRAMES = 3


@pytest.fixture(scope="session")
def quantised(synth_log, tmp_path_factory):
    """``quantised(kind) -> SemanticKittiReader`` of a log on that kind's quantum: ``unit``
    (float32, untouched), ``uint8``/``uint16`` remission, ``las`` (uint16 + 1 mm grid), ``ascii``
    (every 8th point, values that survive printing with 10 decimals)."""
    made: dict[str, SemanticKittiReader] = {}
    kinds = {
        "unit": {},
        "uint8": {"convention": "uint8"},
        "uint16": {"convention": "uint16"},
        "none": {"convention": "none"},
        "las": {"convention": "uint16", "xyz_scale": 0.001},
        "ascii": {"decimals": 10, "every": 8},
    }

    def get(kind: str) -> SemanticKittiReader:
        if kind not in made:
            root: Path = tmp_path_factory.mktemp(f"q_{kind}")
            made[kind] = SemanticKittiReader(quantised_log(synth_log, root, FRAMES, **kinds[kind]))
        return made[kind]

    return get
