"""A tiny labelled log in the SemanticKITTI layout, written with ``write_frame`` (until the
synthetic generator lands): road, sidewalk, a building wall, vegetation, a moving car and a person."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dsnet_core.io.semantickitti import write_frame, write_sequence_meta


def _box(rng, centre, size, n):
    return centre + (rng.random((n, 3)) - 0.5) * size


def tiny_frame(index: int, seed: int = 0, n: int = 3000) -> tuple[np.ndarray, np.ndarray]:
    """float32 ``(N, 4)`` points and uint32 ``(N,)`` labels (raw semantic | instance << 16)."""
    rng = np.random.default_rng([seed, index])
    parts = []

    def ring(r0, r1, z, k, raw):
        r = np.sqrt(rng.uniform(r0**2, r1**2, k))
        a = rng.uniform(-np.pi, np.pi, k)
        parts.append((np.stack([r * np.cos(a), r * np.sin(a), np.full(k, z)], 1), raw, 0))

    ring(3.5, 15.0, -1.7, n // 3, 40)  # road
    ring(16.0, 20.0, -1.6, n // 6, 48)  # sidewalk
    a = rng.uniform(-np.pi, np.pi, n // 6)
    wall = np.stack([22 * np.cos(a), 22 * np.sin(a), rng.uniform(-1.6, 1.2, n // 6)], 1)
    parts.append((wall, 50, 0))
    parts.append((_box(rng, np.array([0.0, 11.0, -0.5]), np.array([3.0, 2.5, 2.0]), n // 8), 70, 0))
    car = np.array([7.0 + 0.8 * index, 4.0, -0.95])
    parts.append((_box(rng, car, np.array([4.0, 1.8, 1.5]), n // 8), 10, 1))
    parts.append((_box(rng, np.array([-6.0, -5.0, -0.85]), np.array([0.6, 0.6, 1.7]), n // 12), 30, 2))
    pts = np.concatenate([p for p, _, _ in parts]).astype(np.float32)
    labels = np.concatenate([np.full(len(p), raw | (inst << 16), np.uint32) for p, raw, inst in parts])
    remission = rng.random((len(pts), 1)).astype(np.float32)
    return np.concatenate([pts, remission], 1), labels


def write_tiny_log(root: Path, frames: int = 2, sequence: str = "00", seed: int = 0, n: int = 3000) -> Path:
    """Write ``frames`` frames of about ``n`` points (with identity-based poses) under
    ``root/sequences/<sequence>``."""
    seq = Path(root) / "sequences" / sequence
    for i in range(frames):
        pts, lab = tiny_frame(i, seed, n)
        write_frame(seq, f"{i:06d}", pts, lab)
    poses = np.repeat(np.eye(4)[None], frames, 0)
    poses[:, 0, 3] = np.arange(frames) * 0.5
    write_sequence_meta(seq, poses, np.eye(4), np.arange(frames) * 0.1)
    return Path(root)
