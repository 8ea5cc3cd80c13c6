"""The extras a user needs for an input format are the ones the tests run with: ``dev`` (what
``make test`` installs) holds every ``formats`` requirement with the same pins, so a format that
passes the tests also labels on an install with ``pip install '.[formats]'``."""

from __future__ import annotations

import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_dev_installs_the_formats_extra_with_its_pins():
    extras = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"]
    assert set(extras["formats"]) <= set(extras["dev"]), set(extras["formats"]) - set(extras["dev"])
    readme = (ROOT / "README.md").read_text()
    assert "pip install '.[formats]'" in readme and "rosbag" in readme
