"""Tiny synthetic street scenes with thing instances, for the oracle tests and the shifting ablation.

Not the project's LiDAR simulator (``dsnet_core.synth`` ray-casts full logs): a sensor at the
origin, a road along x with sidewalks and building facades (stuff), and cars, trucks, people and
cyclists as boxes (things) whose sensor-facing faces are sampled with a density falling with
range², so far objects get few points as in a real scan. People often walk in pairs a metre
apart and cars park in rows, which is what makes clustering hard. Deterministic given the seed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

SENSOR_HEIGHT = 1.73
# train id: (length, width, height) in metres
THING_SIZES = {1: (4.3, 1.8, 1.5), 4: (8.0, 2.5, 3.2), 6: (0.6, 0.6, 1.75), 7: (1.8, 0.6, 1.7)}
ROAD, SIDEWALK, BUILDING = 9, 11, 13


@dataclass(frozen=True)
class ToyScene:
    """One scan. xyz float32 (N, 3) metres; semantic int64 (N,) train ids; instance int64 (N,)
    (0 on stuff, 1..K on things)."""

    xyz: np.ndarray
    semantic: np.ndarray
    instance: np.ndarray


def _box_surface(rng, centre, size, yaw, density):
    """Points on the faces of a yawed box that face the sensor at the origin."""
    length, width, height = size
    half = np.array([length, width, height]) / 2
    rot = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]])
    pts = []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            normal = np.zeros(3)
            normal[axis] = sign
            face_centre = centre + rot @ (normal * half)
            if np.dot(rot @ normal, face_centre) >= 0 and axis != 2:
                continue  # faces away from the sensor
            if axis == 2 and sign < 0:
                continue  # bottom
            dims = [d for d in range(3) if d != axis]
            area = 4 * half[dims[0]] * half[dims[1]]
            rng_dist = max(np.linalg.norm(face_centre), 2.0)
            n = rng.poisson(density * area / rng_dist**2)
            local = rng.uniform(-1, 1, size=(n, 3)) * half
            local[:, axis] = sign * half[axis]
            pts.append(local @ rot.T + centre)
    return np.concatenate(pts) if pts else np.zeros((0, 3))


def _stuff(rng, density):
    r = np.sqrt(rng.uniform(9, 50**2, size=int(density / 60)))
    phi = rng.uniform(-np.pi, np.pi, size=r.size)
    ground = np.stack([r * np.cos(phi), r * np.sin(phi), np.full(r.size, -SENSOR_HEIGHT)], axis=1)
    ground[:, 2] += rng.normal(0, 0.02, r.size)
    ground_cls = np.where(np.abs(ground[:, 1]) < 7, ROAD, SIDEWALK)
    walls = []
    for side in (-1.0, 1.0):
        n = int(density / 400)
        x = rng.uniform(-50, 50, n)
        z = rng.uniform(-SENSOR_HEIGHT, 6, n)
        walls.append(np.stack([x, np.full(n, side * 12.0) + rng.normal(0, 0.03, n), z], axis=1))
    wall = np.concatenate(walls)
    xyz = np.concatenate([ground, wall])
    cls = np.concatenate([ground_cls, np.full(len(wall), BUILDING)])
    return xyz, cls


def _placements(rng, n_objects):
    """(class, centre, yaw) of non-overlapping objects: cars/trucks on the road and parked at its
    edges, people and cyclists on the sidewalks, often in pairs."""
    out = []
    footprints = []

    def free(c, size, yaw):
        rad = 0.5 * np.hypot(size[0], size[1])
        return all(np.hypot(*(c[:2] - c2[:2])) > rad + r2 + 0.15 for c2, r2 in footprints)

    tries = 0
    while len(out) < n_objects and tries < 50 * n_objects:
        tries += 1
        cls = int(rng.choice([1, 1, 1, 4, 6, 6, 7]))
        size = THING_SIZES[cls]
        if cls in (1, 4):
            y = float(rng.choice([-5.5, -2.0, 2.0, 5.5])) + rng.normal(0, 0.2)
            yaw = rng.normal(0, 0.08)
        else:
            y = float(rng.choice([-1.0, 1.0])) * rng.uniform(7.5, 10.5)
            yaw = rng.uniform(-np.pi, np.pi)
        x = rng.uniform(-45, 45)
        if np.hypot(x, y) < 4:
            continue
        centre = np.array([x, y, -SENSOR_HEIGHT + size[2] / 2])
        group = [centre]
        if cls == 6 and rng.random() < 0.5:  # a second person walking alongside
            d = rng.uniform(0.9, 1.3)
            ang = rng.uniform(0, 2 * np.pi)
            group.append(centre + np.array([d * np.cos(ang), d * np.sin(ang), 0]))
        for c in group:
            if free(c, size, yaw):
                out.append((cls, c, yaw))
                footprints.append((c, 0.5 * np.hypot(size[0], size[1])))
    return out


def make_scene(seed: int, n_objects: int = 30, density: float = 12_000.0) -> ToyScene:
    """A deterministic toy scan.

    Args:
        seed: random seed.
        n_objects: thing instances attempted (placement may fit fewer).
        density: points per m² of surface at 1 m range.
    """
    rng = np.random.default_rng(seed)
    xyz_s, cls_s = _stuff(rng, density * 60)
    xyz_t, cls_t, ins_t = [], [], []
    k = 0
    for cls, centre, yaw in _placements(rng, n_objects):
        pts = _box_surface(rng, centre, THING_SIZES[cls], yaw, density)
        if len(pts) < 3:
            continue
        k += 1
        xyz_t.append(pts)
        cls_t.append(np.full(len(pts), cls))
        ins_t.append(np.full(len(pts), k))
    xyz = np.concatenate([xyz_s, *xyz_t]).astype(np.float32)
    sem = np.concatenate([cls_s, *cls_t]).astype(np.int64)
    inst = np.concatenate([np.zeros(len(xyz_s), np.int64), *ins_t]).astype(np.int64)
    return ToyScene(xyz, sem, inst)
