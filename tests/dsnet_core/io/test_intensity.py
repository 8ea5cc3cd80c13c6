"""The one intensity normalisation: conventions, the inference rule, and typed errors."""

import numpy as np
import pytest

from dsnet_core.errors import DataFormatError, IntensityFormatError
from dsnet_core.io.intensity import infer_convention, normalise_intensity, quantise


def test_conventions_map_to_unit_remission():
    assert np.array_equal(
        normalise_intensity(np.array([0, 51, 255], np.uint8), "uint8", "f"), np.float32([0, 0.2, 1])
    )
    assert np.array_equal(
        normalise_intensity(np.array([0.0, 51.0, 255.0], np.float32), "uint8", "f"), np.float32([0, 0.2, 1])
    )
    assert np.array_equal(
        normalise_intensity(np.array([0, 65535], np.uint16), "uint16", "f"), np.float32([0, 1])
    )
    r = np.float32([0.125, 0.7])
    out = normalise_intensity(r, "unit", "f")
    assert out.dtype == np.float32 and np.array_equal(out, r) and out is not r
    assert np.array_equal(normalise_intensity(None, "none", "f", n_points=3), np.zeros(3, np.float32))


def test_caller_column_is_never_scaled_in_place():
    col = np.float32([10.0, 20.0])
    normalise_intensity(col, "uint8", "f")
    assert col.tolist() == [10.0, 20.0]


def test_inference_rule():
    assert infer_convention(None, "f") == "none"
    assert infer_convention(np.array([3], np.uint8), "f") == "uint8"
    assert infer_convention(np.array([3], np.uint16), "f") == "uint16"
    assert infer_convention(np.float32([0.0, 1.0]), "f") == "unit"
    assert infer_convention(np.float32([0.0, 1.5]), "f") == "uint8"
    assert infer_convention(np.float64([0.0, 255.0]), "f") == "uint8"
    assert infer_convention(np.float32([256.0]), "f") == "uint16"


@pytest.mark.parametrize(
    ("values", "convention", "match"),
    [
        (np.array([1, 2], np.int32), "uint8", "type int32"),
        (np.array(["a"]), "unit", "type <U1"),
        (np.float32([0.5, 300.0]), "uint8", r"span \[0.5, 300\], outside the uint8"),
        (np.float32([-0.1, 0.5]), "unit", "outside the unit"),
        (np.float32([np.nan]), "unit", "NaN"),
        (np.float32([0.5]), "percent", "unknown intensity convention"),
    ],
)
def test_errors_name_the_file(values, convention, match):
    with pytest.raises(IntensityFormatError, match=match) as err:
        normalise_intensity(values, convention, "/logs/a.pcd")
    assert isinstance(err.value, DataFormatError)
    assert str(err.value).startswith("/logs/a.pcd: ") and "\n" not in str(err.value)


def test_inference_rejects_out_of_range_floats():
    with pytest.raises(IntensityFormatError, match="above every convention"):
        infer_convention(np.float32([70000.0]), "/logs/a.ply")


@pytest.mark.parametrize(("convention", "dtype"), [("uint8", np.uint8), ("uint16", np.uint16)])
def test_quantised_values_round_trip_exactly(convention, dtype):
    r = np.random.default_rng(0).random(1000).astype(np.float32)
    q = quantise(r, convention)
    as_int = normalise_intensity(q.astype(dtype), convention, "f")
    as_float = normalise_intensity(q.astype(np.float32), convention, "f")
    assert np.array_equal(as_int, as_float)
    assert np.abs(as_int - r).max() <= 0.5 / {"uint8": 255, "uint16": 65535}[convention] + 1e-7
