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
    assert "pip install -c constraints/lock.txt '.[formats]'" in readme and "rosbag" in readme


def _name(requirement: str) -> str:
    import re

    return re.split(r"[\[<>=!~; ]", requirement, maxsplit=1)[0].lower().replace("_", "-")


def test_the_lock_pins_every_requirement_and_sqlalchemy_2_0():
    """A fresh install resolves what the tests ran with: make passes constraints/lock.txt, which
    pins every direct and dev requirement (torch aside: the Makefile installs its CPU build) and
    keeps SQLAlchemy at 2.0.x (with 2.1 Prefect 3.8's scheduler never creates a run)."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    lock = {}
    for line in (ROOT / "constraints" / "lock.txt").read_text().splitlines():
        if line.strip() and not line.startswith("#"):
            name, _, version = line.partition("==")
            lock[_name(name)] = version.strip()
    wanted = {_name(r) for r in project["dependencies"] + project["optional-dependencies"]["dev"]}
    assert wanted - {"torch"} <= set(lock), sorted(wanted - {"torch"} - set(lock))
    assert lock["sqlalchemy"].startswith("2.0."), lock["sqlalchemy"]
    assert lock["prefect"].startswith("3.8.")
    assert "-c $(CONSTRAINTS)" in (ROOT / "Makefile").read_text()


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
