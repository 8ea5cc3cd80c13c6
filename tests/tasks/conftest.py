"""Fixtures of the stage tests."""

import pytest

from tests.tasks.oracle_stitch import install


@pytest.fixture
def oracle_stages(monkeypatch):
    """The stand-in stitch stage (perturbed ground truth) and the score stage, for one test."""
    return install(monkeypatch)
