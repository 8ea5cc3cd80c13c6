"""A small synthetic street for the refinement tests: ground-truth labels, poses and points, fast.

The ego drives along +x at 8 m/s (10 Hz) past a road, sidewalks, a building front, a hedge and
poles, a parked car (id 1), a car overtaking on the next lane (id 2, 14 m/s) and a walking person
(id 3). Points are drawn uniformly on each surface within 30 m of the ego in every frame (no
occlusion), so every static voxel is seen in many frames. Train ids of the SemanticKITTI map.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from dsnet_core.labels import load_label_map
from dsnet_core.refine import ClassSets, FrameInput
from dsnet_core.refine.frame import Confidence

LM = load_label_map("semantic-kitti")
SETS = ClassSets.from_label_map(LM)
CAR, TRUCK, PERSON = 1, 4, 6
ROAD, SIDEWALK, BUILDING, VEGETATION, POLE = 9, 11, 13, 15, 18
STATIC_CLASSES = (ROAD, SIDEWALK, BUILDING, VEGETATION, POLE)
EGO_SPEED, HEIGHT, RANGE = 8.0, 1.7, 30.0
PARKED = np.array([40.0, -3.0, 1.05])  # centre, metres
CAR_SIZE = np.array([4.5, 1.8, 1.5])


def _plane(rng, n, x0, x1, y0, y1, z):
    return np.stack([rng.uniform(x0, x1, n), rng.uniform(y0, y1, n), np.full(n, z)], 1)


def _box_surface(rng, centre, size, n):
    """Points on the faces of an axis-aligned box."""
    p = rng.uniform(-0.5, 0.5, (n, 3))
    face = rng.integers(0, 3, n)
    p[np.arange(n), face] = np.where(rng.random(n) < 0.5, -0.5, 0.5)
    return centre + p * size


def moving_car_centre(t: float) -> np.ndarray:
    return np.array([-5.0 + 14.0 * t, -1.2, 1.05])


def person_centre(t: float) -> np.ndarray:
    return np.array([25.0 + 1.4 * t, 6.0, 0.95])


def frame(index: int, seed: int = 0, density: float = 1.0) -> FrameInput:
    """Ground truth of frame ``index``: sensor-frame points, train ids, ids and the pose."""
    rng = np.random.default_rng([seed, index])
    t = 0.1 * index
    ego = np.array([EGO_SPEED * t, 0.0, HEIGHT])
    x0, x1 = ego[0] - RANGE, ego[0] + RANGE
    k = lambda n: int(n * density)  # noqa: E731
    parts = []
    road = _plane(rng, k(3000), x0, x1, -4.0, 4.0, 0.0)
    inside = (np.abs(road[:, 0] - PARKED[0]) < CAR_SIZE[0] / 2) & (
        np.abs(road[:, 1] - PARKED[1]) < CAR_SIZE[1] / 2
    )
    parts.append((road[~inside], ROAD, 0))
    parts.append((_plane(rng, k(800), x0, x1, 4.5, 7.0, 0.15), SIDEWALK, 0))
    parts.append((_plane(rng, k(800), x0, x1, -7.0, -4.5, 0.15), SIDEWALK, 0))
    wall = np.stack([rng.uniform(x0, x1, k(1200)), np.full(k(1200), 9.0), rng.uniform(0.0, 6.0, k(1200))], 1)
    parts.append((wall, BUILDING, 0))
    hedge = np.stack(
        [rng.uniform(x0, x1, k(800)), rng.uniform(-9.0, -8.0, k(800)), rng.uniform(0.3, 2.5, k(800))], 1
    )
    parts.append((hedge, VEGETATION, 0))
    poles = np.arange(np.ceil(x0 / 10.0) * 10.0, x1, 10.0)
    if poles.size:
        n = k(60) * poles.size
        a = rng.uniform(0, 2 * np.pi, n)
        pole = np.stack(
            [np.repeat(poles, k(60)) + 0.1 * np.cos(a), 7.6 + 0.1 * np.sin(a), rng.uniform(0.3, 4.0, n)], 1
        )
        parts.append((pole, POLE, 0))
    for centre, size, cls, inst, n in (
        (PARKED, CAR_SIZE, CAR, 1, 400),
        (moving_car_centre(t), CAR_SIZE, CAR, 2, 400),
        (person_centre(t), np.array([0.5, 0.5, 1.3]), PERSON, 3, 120),
    ):
        if abs(centre[0] - ego[0]) < RANGE:
            parts.append((_box_surface(rng, centre, size, k(n)), cls, inst))
    world = np.concatenate([p for p, _, _ in parts])
    sem = np.concatenate([np.full(len(p), c, np.int64) for p, c, _ in parts])
    inst = np.concatenate([np.full(len(p), i, np.int64) for p, _, i in parts])
    pose = np.eye(4)
    pose[:3, 3] = ego
    xyz = (world - ego).astype(np.float32)
    return FrameInput(index, t, pose, xyz, sem, inst)


def sequence(n_frames: int = 30, seed: int = 0, density: float = 1.0) -> list[FrameInput]:
    return [frame(i, seed, density) for i in range(n_frames)]


def static_points(f: FrameInput) -> np.ndarray:
    """``(N,) bool``: stuff points and points of the parked car."""
    return SETS.stuff[f.sem] | (f.inst == 1)


def add_static_noise(frames: list[FrameInput], share: float, seed: int = 1) -> tuple[list[FrameInput], list]:
    """Give ``share`` of each frame's static points another class (drawn uniformly from the other
    scored classes; ids unchanged). Returns the noisy frames and each frame's noised mask."""
    out, masks = [], []
    for f in frames:
        rng = np.random.default_rng([seed, f.index])
        noised = static_points(f) & (rng.random(f.n_points) < share)
        sem = f.sem.copy()
        other = rng.integers(1, LM.num_classes - 1, noised.sum())
        sem[noised] = np.where(other >= sem[noised], other + 1, other)
        out.append(replace(f, sem=sem))
        masks.append(noised)
    return out, masks


def soft_probs(f: FrameInput, sharpness: float = 0.7, seed: int = 2) -> FrameInput:
    """The frame with quantised probabilities: ``sharpness`` on its class, the rest spread at random."""
    rng = np.random.default_rng([seed, f.index])
    p = rng.random((f.n_points, LM.num_classes))
    p[:, 0] = 0
    p *= (1 - sharpness) / p.sum(axis=1, keepdims=True)
    p[np.arange(f.n_points), f.sem] += sharpness
    return replace(f, probs=np.rint(p * 255).astype(np.uint8))


def plan_confidence(confidence: dict[int, float] | None = None) -> Confidence:
    """Vote weights from ``{id: confidence}`` (None: full weight)."""
    return Confidence.from_mapping(confidence)
