"""LiDAR presets: beam layouts, and the per-sequence draws of mounting, noise and remission."""

import numpy as np
import pytest

from dsnet_core.errors import ConfigError
from dsnet_core.synth import SENSORS, get_sensor
from dsnet_core.synth.log import child_seed, sequence_seed
from dsnet_core.synth.variation import choose_setup


@pytest.mark.parametrize(
    ("name", "beams", "top", "bottom", "uniform"),
    [
        ("hdl64", 64, 2.0, -24.9, False),
        ("vlp32", 32, 15.0, -25.0, False),
        ("nuscenes32", 32, 10.0, -30.0, True),
        ("ouster64", 64, 22.5, -22.5, True),
        ("ouster128", 128, 22.5, -22.5, True),
        ("vlp16", 16, 15.0, -15.0, True),
    ],
)
def test_beam_elevations(name, beams, top, bottom, uniform):
    spec = get_sensor(name)
    el = np.asarray(spec.elevations_deg)
    assert spec.beams == beams and el[0] == pytest.approx(top) and el[-1] == pytest.approx(bottom)
    assert (np.diff(el) < 0).all(), "top beam first"
    if uniform:
        np.testing.assert_allclose(np.diff(el), (bottom - top) / (beams - 1))
    dirs = spec.directions()
    assert dirs.shape == (spec.rays, 3)
    np.testing.assert_allclose(np.degrees(np.arcsin(dirs[:: spec.azimuth_steps, 2])), el, atol=1e-9)
    assert len(spec.beam_gains) == beams


def test_vlp16_is_two_degrees_apart():
    assert np.diff(get_sensor("vlp16").elevations_deg) == pytest.approx([-2.0] * 15)


def test_legacy_default_draws_nothing():
    for sensor in ("hdl64", "vlp32"):
        setup = choose_setup(child_seed(sequence_seed(0, 0), 2), "classic", sensor)
        assert not setup.randomised and setup.spec == get_sensor(sensor)
        np.testing.assert_array_equal(setup.mount(), np.eye(4))


@pytest.mark.parametrize("sensor", sorted(set(SENSORS) - {"hdl64", "vlp32"}))
def test_new_sensors_draw_mounting_noise_and_remission(sensor):
    setups = [choose_setup(child_seed(sequence_seed(0, i), 2), "classic", sensor) for i in range(4)]
    assert all(s.randomised and s.sensor == sensor for s in setups)
    heights = [s.spec.height for s in setups]
    assert all(1.5 <= h <= 2.2 for h in heights) and len(set(heights)) == 4
    assert len({s.spec.remission_gain for s in setups}) == 4 and len({s.mount_pitch_deg for s in setups}) == 4
    again = choose_setup(child_seed(sequence_seed(0, 0), 2), "classic", sensor)
    assert again == setups[0], "deterministic per seed"


def test_random_draws_every_sensor_and_respects_a_list():
    drawn = {choose_setup(child_seed(sequence_seed(s, 0), 2), "classic", "random").sensor for s in range(80)}
    assert drawn == set(SENSORS)
    subset = {
        choose_setup(
            child_seed(sequence_seed(s, 0), 2), "classic", "random", sensors=["vlp16", "ouster64"]
        ).sensor
        for s in range(20)
    }
    assert subset == {"vlp16", "ouster64"}
    with pytest.raises(ConfigError, match="unknown sensor"):
        choose_setup(child_seed(sequence_seed(0, 0), 2), "classic", "random", sensors=["hdl32"])
