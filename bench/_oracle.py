"""Shared set-up of the shifting benchmarks: synthetic logs with oracle centres and features.

Ground-truth semantics stand in for the prediction; regressed centres are ground-truth box
centres plus ``dsnet_core.oracle.inputs`` noise; features are ``oracle_features``. Scored with the
project's SemanticKITTI evaluator (official mode; PQ^Th over the 8 thing classes).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from dsnet_core.instance.fusion import fuse
from dsnet_core.io.semantickitti import SemanticKittiReader
from dsnet_core.labels import load_label_map
from dsnet_core.metrics import PanopticEvaluator
from dsnet_core.oracle.inputs import oracle_inputs
from dsnet_core.synth import generate_log

LABEL_MAP = load_label_map("semantic-kitti")


@dataclass
class OracleScan:
    xyz: np.ndarray  # (N, 3) all points
    semantic: np.ndarray  # (N,) gt train ids (used as the prediction: oracle semantics)
    instance: np.ndarray  # (N,) gt instance ids
    thing: np.ndarray  # (N,) bool
    centres: np.ndarray  # (M, 3) regressed (noisy) centres of the thing points
    gt_centres: np.ndarray  # (M, 3)
    features: np.ndarray  # (M, 32) oracle features


def oracle_scans(root: Path, noise_seed: int, noise_scale: float = 1.0) -> list[OracleScan]:
    """Every frame of the SemanticKITTI-layout log at ``root`` as oracle inputs."""
    reader = SemanticKittiReader(root)
    scans = []
    for seq in reader.sequences():
        for frame in reader.frames(seq):
            pts = reader.scan(frame)
            lab = reader.labels(frame, len(pts))
            sem = LABEL_MAP.to_train(lab & 0xFFFF).astype(np.int64)
            inst = (lab >> 16).astype(np.int64)
            xyz = np.ascontiguousarray(pts[:, :3])
            o = oracle_inputs(xyz, sem, inst, LABEL_MAP.things, noise_seed + len(scans), noise_scale)
            scans.append(OracleScan(xyz, sem, inst, o.thing, o.centres, o.gt_centres, o.features))
    return scans


def synth_scans(
    root: Path, seed: int, sequences: int, frames: int, noise_scale: float = 1.0, sensor: str = "hdl64"
) -> list[OracleScan]:
    """Oracle scans of a synthetic log, generated into ``root`` unless it is already there."""
    if not (root / "sequences").exists():
        generate_log(root, sequences=sequences, frames=frames, seed=seed, sensor=sensor)
    return oracle_scans(root, noise_seed=10_000 * seed, noise_scale=noise_scale)


def score(scans: list[OracleScan], clusterer) -> tuple[float, dict[str, float]]:
    """PQ^Th (official SemanticKITTI semantics) and per-thing-class PQ of ``clusterer`` + fusion."""
    ev = PanopticEvaluator(LABEL_MAP, keep_rows=False)
    for s in scans:
        ids = clusterer.cluster(s.xyz[s.thing], s.centres, s.features)
        inst = np.zeros(len(s.xyz), np.int64)
        inst[s.thing] = ids
        fused = fuse(s.xyz, s.semantic, inst, LABEL_MAP.things)
        ev.add_train(s.semantic, s.instance, fused.semantic, fused.instance)
    res = ev.result().panoptic
    return res.pq_things, {k: v.pq for k, v in res.per_class.items() if v.thing}
