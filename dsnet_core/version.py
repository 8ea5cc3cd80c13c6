"""The one code version the product records (model cards, run configs): what wrote a file."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path


def code_version() -> str:
    """``$DSNET_CODE_VERSION``, else the git commit of this code, else the package version."""
    if os.environ.get("DSNET_CODE_VERSION"):
        return os.environ["DSNET_CODE_VERSION"]
    here = Path(__file__).resolve().parent
    try:
        sha = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=here, capture_output=True, text=True, timeout=5, check=True
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=here,
            capture_output=True,
            text=True,
            timeout=5,
        ).stdout.strip()
        return sha + ("-dirty" if dirty else "")
    except (OSError, subprocess.SubprocessError):
        from importlib.metadata import PackageNotFoundError, version

        try:
            return version("dsnet-pipeline")
        except PackageNotFoundError:
            return "unknown"
