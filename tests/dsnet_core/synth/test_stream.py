"""The training stream: pure in (seed, step), distinct per step, restrictable, and the same with
background workers as without."""

import numpy as np
import pytest

from dsnet_core.errors import ConfigError
from dsnet_core.synth.stream import StreamOptions, SynthStream, stream_sample

OPTIONS = StreamOptions(frames=2, sensors=("vlp16",))  # the cheapest sensor keeps this fast


def _same(a, b) -> bool:
    return (
        a.setup == b.setup
        and np.array_equal(a.poses, b.poses)
        and all(np.array_equal(x, y) for x, y in zip(a.scans, b.scans, strict=True))
        and all(np.array_equal(x, y) for x, y in zip(a.labels, b.labels, strict=True))
    )


def test_sample_is_pure_and_distinct_per_step():
    a, b, again = stream_sample(0, 0, OPTIONS), stream_sample(0, 1, OPTIONS), stream_sample(0, 0, OPTIONS)
    assert _same(a, again)
    assert not np.array_equal(a.scans[0][:100], b.scans[0][:100])
    assert (
        len(a.scans) == len(a.labels) == 2 and a.poses.shape == (2, 4, 4) and a.times.tolist() == [0.0, 0.1]
    )
    np.testing.assert_allclose(a.poses[0], np.eye(4), atol=1e-12)
    assert a.scans[0].dtype == np.float32 and a.labels[0].dtype == np.uint32
    assert a.labels[0].shape == (a.scans[0].shape[0],)
    assert a.setup["sensor"] == "vlp16" and a.setup["randomised"]
    other = stream_sample(1, 0, StreamOptions(frames=1, sensors=("vlp16",)))
    assert not np.array_equal(a.scans[0][:100], other.scans[0][:100]), "another seed, another stream"


def test_restricted_styles_hold_out_the_rest():
    opts = StreamOptions(frames=1, styles=("country", "parking_lot"), sensors=("vlp16",))
    styles = {s.setup["style"] for s in SynthStream(0, 1, styles=opts.styles, sensors=opts.sensors, count=3)}
    assert styles <= {"country", "parking_lot"}


def test_prefetching_workers_match_the_serial_stream():
    kwargs = {"frames": 1, "sensors": ["vlp16"], "start": 5, "count": 2}
    serial = list(SynthStream(7, **kwargs))
    parallel = list(SynthStream(7, workers=1, prefetch=2, **kwargs))
    assert [s.step for s in parallel] == [5, 6]
    assert all(_same(a, b) for a, b in zip(serial, parallel, strict=True))


def test_bad_stream_arguments():
    with pytest.raises(ConfigError, match="step must be ≥ 0"):
        stream_sample(0, -1)
    with pytest.raises(ConfigError, match="unknown style"):
        SynthStream(0, styles=["suburb"])
