"""Sensor cards: YAML round trip, and a bad card is one typed line naming the file and the key."""

from __future__ import annotations

import pytest
import yaml

from dsnet_core.sensor import SensorCardError, load_card, parse_card
from dsnet_core.synth.card_sensor import spec_from_card


def _card(beams: int = 3) -> dict:
    return {
        "card": 1,
        "name": "tiny",
        "beams": beams,
        "elevations_deg": [2.0, -5.0, -15.0][:beams],
        "azimuth_steps": 360,
        "fov_deg": 90.0,
        "mount_height_m": 1.8,
        "min_range_m": 1.0,
        "max_range_m": 80.0,
        "returns_per_scan": 600.0,
        "range_noise_m": 0.02,
        "ray_drop": {
            "rate": 0.05,
            "per_beam": [0.05] * beams,
            "beam_factor": [1.0] * beams,
            "range_edges_m": [0.0, 40.0, 80.0],
            "by_range": [0.04, 0.08],
        },
        "remission": {
            "levels": [0.0, 0.5, 1.0],
            "quantiles": [0.0, 0.2, 0.9],
            "range_edges_m": [0.0, 80.0],
            "by_range": [[0.0, 0.2, 0.9]],
        },
    }


def test_a_card_survives_yaml_and_becomes_a_spec(tmp_path):
    card = parse_card(_card())
    path = card.save(tmp_path / "card.yaml")
    again = load_card(path)
    assert again == card
    spec = spec_from_card(again)
    assert spec.beams == 3 and spec.columns().size == 90 and spec.directions().shape == (270, 3)
    assert spec.height == 1.8 and spec.max_range == 80.0


@pytest.mark.parametrize(
    ("edit", "line"),
    [
        ({"beams": 0}, "beams: Input should be greater than or equal to 1, got 0"),
        ({"beams": 10_000}, "beams: Input should be less than or equal to 512, got 10000"),
        ({"elevations_deg": [2.0, -5.0, -95.0]}, "elevations_deg: entry 2 is -95.0°, outside ±90°"),
        ({"mount_height_m": -0.5}, "mount_height_m: Input should be greater than or equal to 0, got -0.5"),
        ({"colour": "red"}, "colour: unknown key (see docs/sensor.md for the card's keys)"),
        ({"elevations_deg": [2.0, -5.0]}, "card: elevations_deg holds 2 angles for 3 beams"),
        ({"ray_drop": {**_card()["ray_drop"], "speed": 1}}, "ray_drop.speed: unknown key"),
        ({"origin": {"xyz_m": [0.0, 0.0, 250.0]}}, "origin.xyz_m: entry 2 is 250.0 m, outside ±100 m"),
        ({"origin": {"roll_deg": 60}}, "origin.roll_deg: Input should be less than or equal to 45, got 60"),
        ({"origin": {"yaw_deg": 1}}, "origin.yaw_deg: unknown key"),
    ],
)
def test_a_bad_card_is_one_line_naming_the_file_and_key(tmp_path, edit, line):
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump({**_card(), **edit}))
    with pytest.raises(SensorCardError) as err:
        load_card(path)
    text = str(err.value)
    assert text.startswith(f"{path}: {line}") and "\n" not in text


def test_unreadable_cards(tmp_path):
    with pytest.raises(SensorCardError, match="cannot read the sensor card"):
        load_card(tmp_path / "missing.yaml")
    (tmp_path / "list.yaml").write_text("- 1\n- 2\n")
    with pytest.raises(SensorCardError, match=r"list\.yaml: a sensor card is a YAML mapping"):
        load_card(tmp_path / "list.yaml")
    (tmp_path / "broken.yaml").write_text("beams: [1,\n")
    with pytest.raises(SensorCardError, match=r"broken\.yaml: not YAML at line"):
        load_card(tmp_path / "broken.yaml")
