"""The compiled ASCII number parser against Python's correctly rounded ``float``."""

import numpy as np
import pytest

from dsnet_core.io.asciinum import parse_numbers


@pytest.mark.parametrize("fmt", ["%.18g", "%.9g", "%.10f", "%r", "%.6e", "%.3f"])
def test_float32_values_parse_exactly(fmt):
    rng = np.random.default_rng(7)
    v = np.concatenate(
        [
            (rng.standard_normal(20000) * 10.0 ** rng.integers(-8, 5, 20000)).astype(np.float32),
            np.float32([0, -0.0, 1, 255, 65535, 1e-38, 3.4e38, 123456789]),
        ]
    )
    text = " \n".join((fmt % float(x)) if fmt != "%r" else repr(float(x)) for x in v).encode()
    got, bad = parse_numbers(text, v.size)
    want = np.array([float(t) for t in text.split()])
    assert bad is None and got.size == v.size
    assert np.array_equal(got.astype(np.float32), want.astype(np.float32))
    ulp = np.spacing(np.abs(want))
    assert (np.abs(got - want) <= 2 * ulp).all()


def test_tokens_counts_and_errors():
    got, bad = parse_numbers(b" 1 -2.5e3\t+.5 5. NaN -inf Infinity\r\n7E-2 ", 10)
    assert bad is None and got[:3].tolist() == [1, -2500, 0.5] and got[3] == 5
    assert np.isnan(got[4]) and got[5] == -np.inf and got[6] == np.inf and got[7] == 0.07 and got.size == 8
    assert parse_numbers(b"1 2 3 4", 2)[0].tolist() == [1, 2]
    for text, offset in ((b"1 2x 3", 2), (b"1 - 3", 2), (b"1 1e 3", 2), (b"abc", 0), (b"1 nana", 2)):
        got, bad = parse_numbers(text, 3)
        assert bad == offset and got.size == (1 if offset else 0)
