"""``dsnet describe --sensor`` and ``dsnet synth --sensor-card / --like`` as a user runs them."""

import yaml

from dsnet_core.synth import generate_log
from tests.flows.test_cli_synth import dsnet


def test_describe_sensor_writes_a_card_that_synth_renders(tmp_path):
    log = tmp_path / "log"
    generate_log(log, sequences=1, frames=1, seed=0, sensor="vlp16")
    card = tmp_path / "card.yaml"
    res = dsnet("describe", str(log), "--sensor", "--out", str(card))
    assert res.returncode == 0, res.stderr
    assert "beams: 16, elevations +15.000° … -15.000°" in res.stdout
    assert "could not estimate:\n  elevations_deg: from 1 scan" in res.stdout
    assert "frame_period_s: 1 scan: no time between scans" in res.stdout
    assert yaml.safe_load(card.read_text())["beams"] == 16
    res = dsnet("synth", str(tmp_path / "out"), "--frames", "1", "--sensor-card", str(card))
    assert res.returncode == 0, res.stderr
    assert "(sensor card log: 16 beams)" in res.stdout
    res = dsnet("synth", str(tmp_path / "like"), "--frames", "1", "--like", str(log))
    assert res.returncode == 0, res.stderr
    assert yaml.safe_load((tmp_path / "like/sensor_card.yaml").read_text())["beams"] == 16


def test_a_bad_card_is_one_line(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("beams: 0\n")
    res = dsnet("synth", str(tmp_path / "out"), "--sensor-card", str(bad))
    assert res.returncode == 2
    assert (
        res.stderr.strip()
        .splitlines()[-1]
        .endswith(f"{bad}: beams: Input should be greater than or equal to 1, got 0")
    )
    res = dsnet("synth", str(tmp_path / "out"), "--sensor-card", str(bad), "--sensor", "vlp16")
    assert res.returncode == 2 and "--sensor-card/--like fix the sensor" in res.stderr
    res = dsnet("describe", str(tmp_path), "--out", str(bad))
    assert res.returncode == 2 and "--out writes the sensor card: give it with --sensor" in res.stderr
