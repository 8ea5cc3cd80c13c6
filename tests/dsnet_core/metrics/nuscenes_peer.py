"""Load nuscenes-devkit's panoptic evaluators without running ``nuscenes/__init__.py``.

The package's ``__init__`` imports the dataset API (cv2, matplotlib, pyquaternion, ...); the two
evaluator modules themselves import only numpy. We load them, unmodified, from the installed
package by giving Python empty parent packages that point at the real folders.
"""

from __future__ import annotations

import importlib
import importlib.util
import sys
import types
from pathlib import Path


def load_nuscenes_evaluators():
    """Return ``(PanopticEval, PanopticTrackingEval)`` or raise ImportError if not installed."""
    spec = importlib.util.find_spec("nuscenes")
    if spec is None or not spec.submodule_search_locations:
        raise ImportError("nuscenes-devkit is not installed")
    root = Path(next(iter(spec.submodule_search_locations)))
    names = ("nuscenes", "nuscenes.eval", "nuscenes.eval.panoptic")
    saved = {n: sys.modules.get(n) for n in names}
    try:
        for name in names:
            if saved[name] is None:
                pkg = types.ModuleType(name)
                pkg.__path__ = [str(root.joinpath(*name.split(".")[1:]))]
                sys.modules[name] = pkg
        seg = importlib.import_module("nuscenes.eval.panoptic.panoptic_seg_evaluator")
        track = importlib.import_module("nuscenes.eval.panoptic.panoptic_track_evaluator")
    finally:
        for name, mod in saved.items():
            if mod is None:
                sys.modules.pop(name, None)
    return seg.PanopticEval, track.PanopticTrackingEval
