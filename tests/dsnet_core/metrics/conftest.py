"""Shared fixture: the SemanticKITTI label map."""

from __future__ import annotations

import pytest

from dsnet_core.labels import load_label_map


@pytest.fixture(scope="session")
def kitti():
    return load_label_map("semantic-kitti")
