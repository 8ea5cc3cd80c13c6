"""Fixtures of the stage tests."""

import pytest

from tests.tasks.oracle_stitch import ORACLE


@pytest.fixture
def oracle_stages():
    """The oracle method: ingest, the stand-in labels stage (perturbed ground truth) and score."""
    return ORACLE
