"""nuscenes-devkit's ``transform_matrix``, loaded without running ``nuscenes/__init__.py`` (which
imports OpenCV and matplotlib): ``nuscenes/utils/geometry_utils.py`` itself needs numpy and
pyquaternion only. Raises ImportError when the devkit (installed ``--no-deps`` by ``make test``)
or pyquaternion is missing."""

from __future__ import annotations

import importlib.util
from pathlib import Path

_spec = importlib.util.find_spec("nuscenes")
if _spec is None or not _spec.submodule_search_locations:
    raise ImportError("nuscenes-devkit is not installed")
_path = Path(next(iter(_spec.submodule_search_locations))) / "utils" / "geometry_utils.py"
_module_spec = importlib.util.spec_from_file_location("_nuscenes_geometry_utils", _path)
_module = importlib.util.module_from_spec(_module_spec)
_module_spec.loader.exec_module(_module)

transform_matrix = _module.transform_matrix
