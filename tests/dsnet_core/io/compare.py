"""Assertions that a reader gives what the SemanticKITTI reader gives on the same (quantised) log."""

from __future__ import annotations

import numpy as np

from dsnet_core.io.semantickitti import SemanticKittiReader

POSE_TOL = 1e-9  # poses pass through text (%.12e camera poses, %.17g, JSON quaternions)


def assert_same_log(
    reader, ref: SemanticKittiReader, labels: bool = False, times_offset: float = 0.0
) -> None:
    """Same frame count, bit-identical float32 scans, poses to 1e-9, timestamps, and labels."""
    (seq,) = reader.sequences()
    got, want = reader.frames(seq), ref.frames("00")
    assert len(got) == len(want)
    for a, b in zip(got, want, strict=True):
        scan, expect = reader.scan(a), ref.scan(b)
        assert scan.dtype == np.float32 and scan.shape == expect.shape
        assert np.array_equal(scan, expect), np.abs(scan - expect).max(axis=0)
        np.testing.assert_allclose(reader.pose(a), ref.pose(b), rtol=0, atol=POSE_TOL)
        assert abs(reader.timestamp(a) - (ref.timestamp(b) + times_offset)) < 1e-6
        if labels:
            assert np.array_equal(reader.labels(a), ref.labels(b))
    np.testing.assert_allclose(reader.poses(seq), ref.poses("00")[: len(want)], rtol=0, atol=POSE_TOL)
