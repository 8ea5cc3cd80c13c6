"""``dsnet synth --physics``: a LiDAR with deliberately altered physics (beam pattern, mounting
height, remission model, ray drop), recorded beside the sequence; bad keys and values refused."""

import json

import numpy as np
import pytest

from dsnet_core.errors import ConfigError
from dsnet_core.io.semantickitti import SemanticKittiReader
from dsnet_core.synth import generate_log, get_sensor
from dsnet_core.synth.physics import apply_physics, elevations, parse_physics

ALTERED = ["elevations=uniform:40:8:-22", "height=2.3", "remission_gain=0.45", "falloff=40", "dropout=0.12"]


def test_parsing_and_applying_the_overrides():
    physics = parse_physics([*ALTERED, "azimuth_steps=1500"])
    assert physics == {
        "elevations": "uniform:40:8:-22",
        "height": 2.3,
        "remission_gain": 0.45,
        "falloff": 40.0,
        "dropout": 0.12,
        "azimuth_steps": 1500,
    }
    spec = apply_physics(get_sensor("hdl64"), physics)
    assert spec.beams == 40 and spec.elevations_deg[0] == 8.0 and spec.elevations_deg[-1] == -22.0
    assert (spec.height, spec.remission_gain, spec.falloff, spec.dropout) == (2.3, 0.45, 40.0, 0.12)
    assert (
        spec.beam_gains == ()
        and spec.azimuth_steps == 1500
        and spec.far_dropout == get_sensor("hdl64").far_dropout
    )
    assert apply_physics(get_sensor("vlp32"), {}) is get_sensor("vlp32")
    assert elevations("1,-5,3") == (3.0, 1.0, -5.0)


@pytest.mark.parametrize(
    ("pair", "message"),
    [
        ("gain=2", "KEY one of elevations, azimuth_steps, height"),
        ("height", "expected KEY=VALUE"),
        ("height=tall", "height wants a number"),
        ("height=0", "height must be > 0"),
        ("dropout=-0.1", "dropout must be ≥ 0"),
        ("dropout=1", "a drop probability must be below 1"),
        ("elevations=uniform:1:5:0", "at least 2 beams"),
        ("elevations=up,down", "expected uniform:B:TOP:BOTTOM"),
    ],
)
def test_bad_physics_is_refused_in_one_line(pair, message):
    with pytest.raises(ConfigError, match=message):
        parse_physics([pair])


def test_a_log_with_altered_physics(tmp_path):
    physics = parse_physics(ALTERED)
    generate_log(tmp_path / "a", frames=1, seed=3, physics=physics)
    generate_log(tmp_path / "b", frames=1, seed=3)
    record = json.loads((tmp_path / "a/sequences/00/synth.json").read_text())
    assert record["physics"] == physics and record["lidar"]["height"] == 2.3
    assert "physics" not in json.loads((tmp_path / "b/sequences/00/synth.json").read_text())
    altered, plain = (SemanticKittiReader(tmp_path / n) for n in "ab")
    scan = altered.scan(altered.frames("00")[0])
    ref = plain.scan(plain.frames("00")[0])
    elev = np.degrees(np.arctan2(scan[:, 2], np.hypot(scan[:, 0], scan[:, 1])))
    assert elev.max() < 8.5 and elev.min() > -22.5  # the new beam pattern (HDL-64: +2° … −24.9°)
    assert len(scan) < 0.75 * len(ref)  # 40 beams and more drop than the 64-beam preset
    assert np.median(scan[:, 3]) < 0.6 * np.median(ref[:, 3])  # darker: lower gain, faster fall-off
