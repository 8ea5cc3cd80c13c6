"""``estimate_sensor`` where the truth is known: logs of every ``dsnet synth`` preset (2 scans each),
a limited-FOV log, a 1-scan log and a log without structure; and the round trip estimate → render
with the card → estimate."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from dsnet_core.errors import ScanFormatError
from dsnet_core.io.formats import open_log
from dsnet_core.io.semantickitti import write_frame
from dsnet_core.sensor import SensorEstimateError, estimate_sensor
from dsnet_core.sensor.compare import card_differences, emd, log_curves
from dsnet_core.synth import SENSORS, generate_log, get_sensor
from tests.dsnet_core.sensor.truth import realised_drop

FRAMES = 2


@pytest.fixture(scope="module")
def preset_logs(tmp_path_factory):
    """preset name -> a 1-sequence × 2-scan classic log of it (seed 0), generated on first use."""
    root = tmp_path_factory.mktemp("presets")
    made: dict[str, Path] = {}

    def log(name: str) -> Path:
        if name not in made:
            generate_log(root / name, sequences=1, frames=FRAMES, seed=0, sensor=name)
            made[name] = root / name
        return made[name]

    return log


def _estimate(root: Path):
    return estimate_sensor(open_log(root), root)


@pytest.mark.parametrize("name", sorted(SENSORS))
def test_every_preset_is_estimated_within_the_tolerances(preset_logs, name):
    root = preset_logs(name)
    card = _estimate(root).card
    spec = get_sensor(name)
    truth = json.loads((root / "sequences/00/synth.json").read_text())["lidar"]
    assert card.beams == spec.beams, "beam count exact"
    np.testing.assert_allclose(card.elevations_deg, spec.elevations_deg, atol=0.1)
    assert card.azimuth_steps == spec.azimuth_steps
    assert card.mount_height_m == pytest.approx(truth["height"], abs=0.05)
    assert card.ray_drop.rate == pytest.approx(realised_drop(name, FRAMES), abs=0.02)
    assert card.range_noise_m == pytest.approx(truth["range_noise"], rel=0.25)
    assert card.fov_deg == 360.0 and card.scan_direction == "counter-clockwise"
    assert card.frame_period_s == pytest.approx(0.1)
    # the simulation limits the true range; the measured one carries the range noise
    assert 0.8 * truth["max_range"] < card.max_range_m <= truth["max_range"] + 5 * truth["range_noise"]
    assert card.not_estimated == {}
    scans = [open_log(root).scan(f) for f in open_log(root).frames("00")]
    assert card.returns_per_scan == pytest.approx(np.mean([s.shape[0] for s in scans]), rel=1e-6)


@pytest.mark.parametrize("name", ["vlp16", "ouster128", "hdl64"])
def test_rendering_the_card_gives_the_same_sensor_back(preset_logs, tmp_path, name):
    """Round trip: estimate → render the same streets with the card → estimate: the same card within
    the tolerances, and as many points per scan (3 %) as the preset rendered."""
    card = _estimate(preset_logs(name)).card
    generate_log(tmp_path, sequences=1, frames=FRAMES, seed=0, sensor_card=card)
    again = _estimate(tmp_path).card
    assert card_differences(card, again) == []
    assert again.returns_per_scan == pytest.approx(card.returns_per_scan, rel=0.03)
    record = json.loads((tmp_path / "sequences/00/synth.json").read_text())
    assert record["sensor_card"]["beams"] == card.beams and record["sensor"] == f"card:{card.name}"
    # the elevation histograms are the same; the range curves close
    a, b = log_curves(_scans(preset_logs(name))), log_curves(_scans(tmp_path))
    assert emd(a.elevation, b.elevation, 0.1) < 0.05
    assert emd(a.per_range, b.per_range, 1.0) < 0.5


def _scans(root: Path) -> list[np.ndarray]:
    reader = open_log(root)
    return [reader.scan(f) for s in reader.sequences() for f in reader.frames(s)]


def _copy_log(src: Path, dst: Path, keep) -> Path:
    """``src``'s sequence 00 with each scan's points filtered by ``keep(scan) -> mask``."""
    seq, out = src / "sequences/00", dst / "sequences/00"
    out.mkdir(parents=True)
    for name in ("poses.txt", "calib.txt", "times.txt"):
        shutil.copy(seq / name, out / name)
    for path in sorted((seq / "velodyne").glob("*.bin")):
        scan = np.fromfile(path, dtype=np.float32).reshape(-1, 4)
        write_frame(out, path.stem, scan[keep(scan)])
    return dst


def test_a_limited_field_of_view(preset_logs, tmp_path):
    def front(scan):
        return np.abs(np.degrees(np.arctan2(scan[:, 1], scan[:, 0]) - 0.3)) < 60.0

    card = _estimate(_copy_log(preset_logs("vlp16"), tmp_path / "front", front)).card
    assert card.beams == 16 and card.azimuth_steps == 1800
    assert card.fov_deg == pytest.approx(120.0, abs=1.0)
    assert card.fov_center_deg == pytest.approx(np.degrees(0.3), abs=1.0)
    generate_log(tmp_path / "again", sequences=1, frames=FRAMES, seed=0, sensor_card=card)
    az = np.degrees(np.concatenate([np.arctan2(s[:, 1], s[:, 0]) for s in _scans(tmp_path / "again")]))
    assert np.abs(az - card.fov_center_deg).max() <= 60.5, "rendered within the card's FOV"
    assert card_differences(card, _estimate(tmp_path / "again").card) == []


def test_one_scan_says_what_it_could_not_estimate(tmp_path):
    generate_log(tmp_path, sequences=1, frames=1, seed=3, sensor="vlp16")
    est = _estimate(tmp_path)
    card = est.card
    assert est.frames_used == est.frames_total == 1
    assert card.beams == 16 and card.frame_period_s is None
    assert card.not_estimated["frame_period_s"] == "1 scan: no time between scans"
    assert "from 1 scan" in card.not_estimated["elevations_deg"]


def test_scans_of_one_repeated_point_are_an_error_not_a_card(preset_logs, tmp_path):
    def same(scan):
        scan[:] = (4.0, 1.0, -1.5, 0.2)
        return np.ones(len(scan), bool)

    root = _copy_log(preset_logs("vlp16"), tmp_path / "same", same)
    with pytest.raises(
        ScanFormatError, match=r"000000.bin: all \d+ points are the same point \(4, 1, -1.5\)"
    ):
        _estimate(root)  # the reader refuses such a scan


class _Stub:
    """A reader whose scans it does not check: every point the same."""

    def sequences(self):
        return ["00"]

    def frames(self, seq):
        return ["a", "b"]

    def scan(self, ref):
        return np.tile(np.float32([4.0, 1.0, -1.5, 0.2]), (500, 1))

    def timestamp(self, ref):
        return None


def test_the_estimate_itself_refuses_scans_of_one_point():
    with pytest.raises(
        SensorEstimateError, match=r"LOG: every point of every scan is the same point \(4.0, 1.0, -1.5\)"
    ):
        estimate_sensor(_Stub(), "LOG")


def test_a_shuffled_scan_has_no_scan_direction(preset_logs, tmp_path):
    def shuffle(scan):
        scan[:] = scan[np.random.default_rng(0).permutation(len(scan))]
        return np.ones(len(scan), bool)

    card = _estimate(_copy_log(preset_logs("vlp16"), tmp_path / "shuffled", shuffle)).card
    assert (
        card.scan_direction is None
        and "order does not follow the spin" in card.not_estimated["scan_direction"]
    )
    assert card.beams == 16


def test_a_jittered_azimuth_is_said_to_be_no_grid(preset_logs, tmp_path):
    def jitter(scan):
        az = np.arctan2(scan[:, 1], scan[:, 0]) + np.random.default_rng(1).uniform(-0.002, 0.002, len(scan))
        h = np.hypot(scan[:, 0], scan[:, 1])
        scan[:, 0], scan[:, 1] = h * np.cos(az), h * np.sin(az)
        return np.ones(len(scan), bool)

    card = _estimate(_copy_log(preset_logs("vlp16"), tmp_path / "jitter", jitter)).card
    assert "not on a fixed grid" in card.not_estimated["azimuth_steps"]
    assert card.beams == 16 and card.azimuth_steps == pytest.approx(
        1800, rel=0.1
    )  # a rough figure, as it says
