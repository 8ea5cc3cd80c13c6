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


def test_every_source_folder_is_a_package_a_wheel_ships():
    # setuptools' find_packages skips a folder without __init__.py: a non-editable install would
    # then lack its modules (dsnet_core/most/ once did)
    from setuptools import find_packages

    found = set(find_packages(str(ROOT), include=["dsnet_core*", "storage*", "tasks*", "flows*"]))
    folders = {
        ".".join(p.parent.relative_to(ROOT).parts)
        for top in ("dsnet_core", "storage", "tasks", "flows")
        for p in (ROOT / top).rglob("*.py")
    }
    assert folders <= found, sorted(folders - found)
