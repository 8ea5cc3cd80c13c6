"""Oracle inputs for the instance stage: ground-truth centres, a regression-noise model and
features computable without a network.

- :func:`box_centres`: DS-Net's offset target, the centre of each instance's axis-aligned tight
  box (not its centroid).
- :func:`noisy_centres`: regressed centres as a trained offset head gets them wrong — error
  elongated along the sensor ray and growing with range, a shared per-instance bias, and a
  fraction of points that under-regress (stop part-way to the centre, typical at object edges).
- :func:`oracle_features`: a 32-d per-point embedding built from the ground-truth class and the
  geometry of the regressed centres, standing in for the backbone's instance feature when the
  shifting MLPs are trained without a network (an *oracle-feature* experiment).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from dsnet_core.instance.radius import radius_sums

NOISE_DEFAULTS = {"radial": (0.08, 0.008), "tangential": (0.04, 0.003), "bias": (0.05, 0.002)}


def box_centres(xyz: np.ndarray, instance: np.ndarray) -> np.ndarray:
    """Per-point centre of its instance's axis-aligned tight box.

    Args:
        xyz: float32 (N, 3) positions, metres.
        instance: int (N,) ids; points with id 0 get their own position.

    Returns:
        float32 (N, 3).
    """
    out = xyz.astype(np.float64).copy()
    mask = instance > 0
    ids, inv = np.unique(instance[mask], return_inverse=True)
    lo = np.full((ids.size, 3), np.inf)
    hi = np.full((ids.size, 3), -np.inf)
    np.minimum.at(lo, inv, out[mask])
    np.maximum.at(hi, inv, out[mask])
    out[mask] = ((lo + hi) / 2)[inv]
    return out.astype(np.float32)


def noisy_centres(
    xyz: np.ndarray,
    centres: np.ndarray,
    instance: np.ndarray,
    seed: int,
    scale: float = 1.0,
    under_fraction: float = 0.05,
) -> np.ndarray:
    """Regressed centres with realistic errors.

    Per point the error is ``N(0, a + b·ρ)`` along the sensor ray and ``N(0, a' + b'·ρ)`` across
    it (ρ = range in metres, coefficients in ``NOISE_DEFAULTS``, times ``scale``), plus a bias
    shared by the instance; ``under_fraction`` of the points only move a uniform 0–60 % of the
    way from the point to the centre.

    Args:
        xyz: float32 (N, 3) thing point positions (sensor at the origin), metres.
        centres: float32 (N, 3) ground-truth centres.
        instance: int (N,) instance ids (for the shared bias).
        seed: random seed.

    Returns:
        float32 (N, 3) regressed centres.
    """
    rng = np.random.default_rng(seed)
    p = xyz.astype(np.float64)
    c = centres.astype(np.float64)
    rho = np.maximum(np.linalg.norm(p, axis=1), 1e-3)
    ray = p / rho[:, None]
    side = np.cross(ray, np.array([0.0, 0.0, 1.0]))
    side /= np.maximum(np.linalg.norm(side, axis=1), 1e-9)[:, None]
    up = np.cross(side, ray)
    (ra, rb), (ta, tb), (ba, bb) = (NOISE_DEFAULTS[k] for k in ("radial", "tangential", "bias"))
    n = p.shape[0]
    err = ray * (rng.normal(size=n) * (ra + rb * rho) * scale)[:, None]
    err += side * (rng.normal(size=n) * (ta + tb * rho) * scale)[:, None]
    err += up * (rng.normal(size=n) * (ta + tb * rho) * scale * 0.5)[:, None]
    ids, inv = np.unique(instance, return_inverse=True)
    inst_rho = np.bincount(inv, weights=rho) / np.bincount(inv)
    bias = rng.normal(size=(ids.size, 3)) * ((ba + bb * inst_rho) * scale)[:, None]
    bias[:, 2] *= 0.3
    out = c + err + bias[inv]
    under = rng.random(n) < under_fraction
    frac = rng.uniform(0.0, 0.6, size=n)
    out[under] = p[under] + frac[under, None] * (c[under] - p[under])
    return out.astype(np.float32)


def oracle_features(xyz: np.ndarray, centres: np.ndarray, semantic: np.ndarray) -> np.ndarray:
    """A 32-d per-point feature from ground-truth classes and regressed-centre geometry.

    Columns: one-hot of the thing class 1..8 (8); range/50, height, offset length (3);
    log(1 + count) of regressed centres within 0.2, 0.65, 1.0, 1.7, 3.2 m of the point's centre
    (5); RMS distance of those neighbours at 1.7 and 3.2 m (2); log(1 + count) of raw points
    within 0.5 and 1.5 m (2); the class one-hot times range/50 (8); the counts at 0.2/1.7/3.2 m
    times range/50 (3); a constant 1 (1).

    Args:
        xyz: float32 (M, 3) thing points; centres: float32 (M, 3) regressed centres;
        semantic: int (M,) thing train ids.

    Returns:
        float32 (M, 32).
    """
    m = xyz.shape[0]
    onehot = np.zeros((m, 8))
    onehot[np.arange(m), np.clip(semantic, 1, 8) - 1] = 1.0
    rho = np.linalg.norm(xyz[:, :2], axis=1, keepdims=True) / 50.0
    offset = np.linalg.norm(centres - xyz, axis=1, keepdims=True)
    c64 = centres.astype(np.float64)
    radii = np.array([0.2, 0.65, 1.0, 1.7, 3.2])
    vals = np.concatenate([c64, (c64 * c64).sum(axis=1, keepdims=True), np.ones((m, 1))], axis=1)
    sums = radius_sums(c64, c64, radii, np.broadcast_to(vals, (5, m, 5)))  # (5, M, 5)
    n = sums[..., 4]
    counts = np.log1p(n).T
    # RMS distance to the neighbours: mean |c_b|² − 2 c_a·mean c_b + |c_a|²
    msq = sums[..., 3] / n - 2 * np.einsum("jmd,md->jm", sums[..., :3] / n[..., None], c64) + vals[:, 3]
    spreads = np.sqrt(np.maximum(msq[[3, 4]], 0.0))
    p64 = xyz.astype(np.float64)
    pn = radius_sums(p64, p64, np.array([0.5, 1.5]), np.ones((2, m, 1)))[..., 0]
    pcounts = np.log1p(pn).T
    feats = np.concatenate(
        [
            onehot,
            rho,
            xyz[:, 2:3] / 2.0,
            offset,
            counts,
            spreads.T,
            pcounts,
            onehot * rho,
            counts[:, [0, 3, 4]] * rho,
            np.ones((m, 1)),
        ],
        axis=1,
    )
    assert feats.shape[1] == 32
    return feats.astype(np.float32)


@dataclass(frozen=True)
class OracleInputs:
    """Oracle stand-ins for the network's outputs on one scan.

    Attributes:
        thing: bool (N,) points of thing classes (ground truth).
        gt_centres: float32 (M, 3) box centres of the thing points' instances.
        centres: float32 (M, 3) regressed centres (``gt_centres`` + :func:`noisy_centres` noise).
        features: float32 (M, 32) :func:`oracle_features`.
    """

    thing: np.ndarray
    gt_centres: np.ndarray
    centres: np.ndarray
    features: np.ndarray


def oracle_inputs(
    xyz: np.ndarray,
    semantic: np.ndarray,
    instance: np.ndarray,
    things: Sequence[int],
    noise_seed: int,
    noise_scale: float = 1.0,
) -> OracleInputs:
    """Oracle centres and features of one scan from its ground truth.

    Args:
        xyz: float32 (N, 3) points, sensor at the origin, metres.
        semantic: int (N,) ground-truth train ids.
        instance: int (N,) ground-truth instance ids (unique within a class).
        things: thing train ids.
        noise_seed: seed of the regression noise.
        noise_scale: multiplies the noise model's standard deviations.
    """
    thing = np.isin(semantic, np.asarray(things))
    p = np.ascontiguousarray(xyz[thing], dtype=np.float32)
    key = semantic[thing].astype(np.int64) * 65536 + instance[thing]
    gt = box_centres(p, key)
    centres = noisy_centres(p, gt, key, seed=noise_seed, scale=noise_scale)
    return OracleInputs(thing, gt, centres, oracle_features(p, centres, semantic[thing]))
