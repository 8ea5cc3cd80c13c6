"""Shared set-up of the shifting benchmarks: toy scenes with oracle centres and features."""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from dsnet_core.fusion import fuse
from dsnet_core.oracle import box_centres, noisy_centres, oracle_features
from dsnet_core.toyscene import make_scene
from tests.dsnet_core.pq_lite import ThingPQ


@dataclass
class OracleScan:
    xyz: np.ndarray  # (N, 3) all points
    semantic: np.ndarray  # (N,) gt train ids (used as the prediction: oracle semantics)
    instance: np.ndarray  # (N,) gt instance ids
    thing: np.ndarray  # (N,) bool
    centres: np.ndarray  # (M, 3) regressed (noisy) centres of the thing points
    gt_centres: np.ndarray  # (M, 3)
    features: np.ndarray  # (M, 32) oracle features


def oracle_scan(scene_seed: int, noise_seed: int, noise_scale: float = 1.0) -> OracleScan:
    sc = make_scene(scene_seed)
    th = sc.instance > 0
    xyz = sc.xyz[th]
    gt = box_centres(xyz, sc.instance[th])
    cen = noisy_centres(xyz, gt, sc.instance[th], seed=noise_seed, scale=noise_scale)
    return OracleScan(
        sc.xyz, sc.semantic, sc.instance, th, cen, gt, oracle_features(xyz, cen, sc.semantic[th])
    )


def score(scans: list[OracleScan], clusterer) -> tuple[float, dict[int, float]]:
    acc = ThingPQ()
    for s in scans:
        ids = clusterer.cluster(s.xyz[s.thing], s.centres, s.features)
        inst = np.zeros(len(s.xyz), np.int64)
        inst[s.thing] = ids
        fused = fuse(s.xyz, s.semantic, inst, range(1, 9))
        acc.add(s.semantic, s.instance, fused.semantic, fused.instance)
    return acc.pq_things(), acc.per_class()
