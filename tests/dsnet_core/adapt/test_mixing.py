"""LiDAR mixing keeps every point of both scans exactly once, paired with its label, instance,
centre and weight; the bands and the sector are where they should be."""

import math

import numpy as np
import pytest

from dsnet_core.adapt import Cloud, laser_mix, mix_pair, polar_mix
from dsnet_core.adapt.mixing import azimuth, inclination
from dsnet_core.errors import ConfigError


def cloud(seed: int, n: int, tag: int) -> Cloud:
    """A random scan whose every point is unique and whose attributes all encode its index."""
    rng = np.random.default_rng(seed)
    r = rng.uniform(3, 40, n)
    a = rng.uniform(-math.pi, math.pi, n)
    z = rng.uniform(-3, 2, n)
    pts = np.stack([r * np.cos(a), r * np.sin(a), z, rng.random(n)], 1).astype(np.float32)
    idx = np.arange(n) + tag
    return Cloud(
        pts,
        idx % 20,
        idx * 7,
        np.stack([idx, -idx, 2 * idx], 1).astype(np.float32),
        (idx % 3).astype(np.float32),
    )


def rows(c: Cloud) -> np.ndarray:
    """Each point with all its attributes as one row, sorted (a multiset of points)."""
    table = np.concatenate(
        [c.points.astype(np.float64), c.sem[:, None], c.inst[:, None], c.centre, c.weight[:, None]], 1
    )
    return table[np.lexsort(table.T[::-1])]


def paired(c: Cloud) -> bool:
    """Every point's label, instance, centre and weight are still its own (tags 0 and 10 000)."""
    idx = c.inst // 7
    return (
        np.array_equal(c.sem, idx % 20)
        and np.array_equal(c.centre[:, 0], idx.astype(np.float32))
        and np.array_equal(c.weight, (idx % 3).astype(np.float32))
    )


A, B = cloud(0, 3000, 0), cloud(1, 2000, 10_000)


@pytest.mark.parametrize("bands", [2, 3, 6])
def test_laser_mix_keeps_every_point_once_and_paired(bands):
    m1, m2 = laser_mix(A, B, bands)
    assert len(m1) + len(m2) == len(A) + len(B)
    both = Cloud(
        *(
            np.concatenate([getattr(m1, f), getattr(m2, f)])
            for f in ("points", "sem", "inst", "centre", "weight")
        )
    )
    assert np.array_equal(
        rows(both),
        rows(
            Cloud(
                *(
                    np.concatenate([getattr(A, f), getattr(B, f)])
                    for f in ("points", "sem", "inst", "centre", "weight")
                )
            )
        ),
    )
    assert paired(m1) and paired(m2)
    # class counts unchanged: the two mixed scans hold the classes of both inputs
    assert np.array_equal(
        np.bincount(np.concatenate([m1.sem, m2.sem]), minlength=20),
        np.bincount(np.concatenate([A.sem, B.sem]), minlength=20),
    )
    # m1: A's points in even bands, B's in odd ones (bands over both scans' inclination range)
    lo = min(inclination(A.points).min(), inclination(B.points).min())
    hi = max(inclination(A.points).max(), inclination(B.points).max())
    band = np.clip(((inclination(m1.points) - lo) / (hi - lo) * bands).astype(int), 0, bands - 1)
    from_a = m1.inst < 7 * 10_000
    assert (band[from_a] % 2 == 0).all() and (band[~from_a] % 2 == 1).all()
    assert from_a.any() and (~from_a).any()


def test_polar_mix_swaps_one_sector_wrapping_at_two_pi():
    start, width = math.radians(300), math.radians(120)  # 300° .. 60°, across 0
    m1, m2 = polar_mix(A, B, start, width)
    assert len(m1) + len(m2) == len(A) + len(B) and paired(m1) and paired(m2)
    inside = np.mod(azimuth(m1.points) - start, 2 * math.pi) < width
    from_a = m1.inst < 7 * 10_000
    assert np.array_equal(inside, ~from_a)  # m1: A outside the sector, B inside
    inside2 = np.mod(azimuth(m2.points) - start, 2 * math.pi) < width
    assert np.array_equal(inside2, m2.inst < 7 * 10_000)  # m2: B outside, A inside
    assert 0.2 < inside.mean() < 0.5


def test_mix_pair_draws_from_the_generator_and_none_keeps_the_scans():
    kinds = {mix_pair(A, B, "both", np.random.default_rng(s))[2] for s in range(12)}
    assert kinds == {"laser", "polar"}
    m1, m2, kind = mix_pair(A, B, "none", np.random.default_rng(0))
    assert kind == "none" and m1 is A and m2 is B
    r1, r2 = (mix_pair(A, B, "both", np.random.default_rng(5)) for _ in range(2))
    assert np.array_equal(r1[0].points, r2[0].points)  # a function of the generator's state
    with pytest.raises(ConfigError, match="unknown mixing 'cutmix'"):
        mix_pair(A, B, "cutmix", np.random.default_rng(0))
    with pytest.raises(ConfigError, match="at least 2 inclination bands"):
        laser_mix(A, B, 1)
