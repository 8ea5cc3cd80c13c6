"""The sensor's centre found from the points (:mod:`dsnet_core.sensor.origin`): a ``dsnet synth`` log
whose scans are moved into a vehicle-like frame by a known offset and tilt gives that offset back,
and ``estimate_sensor`` measures the same sensor from it as from the original."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from dsnet_core.io.formats import open_log
from dsnet_core.io.semantickitti import write_frame
from dsnet_core.sensor import estimate_sensor
from dsnet_core.sensor.card import SensorOrigin
from dsnet_core.sensor.origin import estimate_origin, fit_origin, rotation, to_sensor_frame
from dsnet_core.synth import generate_log, get_sensor

# the sensor 0.8 m ahead of, 0.1 m right of and 1.5 m above the log's origin, pitched down 0.9°
# and rolled 1.5° (a roof LiDAR in a rear-axle frame)
TRUTH = SensorOrigin(xyz_m=(0.8, -0.1, 1.5), roll_deg=1.5, pitch_deg=-0.9)


def _move(scan: np.ndarray, origin: SensorOrigin) -> np.ndarray:
    """``scan`` (sensor frame) as the log's frame holds it: ``R p + xyz``."""
    out = scan.copy()
    out[:, :3] = scan[:, :3].astype(np.float64) @ rotation(origin.roll_deg, origin.pitch_deg).T + origin.xyz_m
    return out


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    """(the vlp32 log, the same log moved by TRUTH) — 2 scans, seed 0."""
    root = tmp_path_factory.mktemp("origin")
    generate_log(root / "orig", sequences=1, frames=2, seed=0, sensor="vlp32")
    src, dst = root / "orig/sequences/00", root / "moved/sequences/00"
    for name in ("calib.txt", "poses.txt", "times.txt"):
        if (src / name).exists():
            dst.mkdir(parents=True, exist_ok=True)
            (dst / name).write_bytes((src / name).read_bytes())
    for path in sorted((src / "velodyne").glob("*.bin")):
        scan = np.fromfile(path, dtype=np.float32).reshape(-1, 4)
        write_frame(dst, path.stem, _move(scan, TRUTH).astype(np.float32))
    return root / "orig", root / "moved"


def _first_scan(root: Path) -> np.ndarray:
    reader = open_log(root)
    return reader.scan(reader.frames(reader.sequences()[0])[0])


def test_a_log_in_its_sensor_frame_keeps_its_origin(logs):
    fit = fit_origin(_first_scan(logs[0]))
    assert fit.exact and not fit.moved and fit.origin == SensorOrigin()


def test_the_offset_and_tilt_are_found_from_the_points(logs):
    scan = _first_scan(logs[1])
    fit = fit_origin(scan)
    assert fit.moved and fit.sharpness > 5 * fit.sharpness_at_log_origin
    np.testing.assert_allclose(fit.origin.xyz_m, TRUTH.xyz_m, atol=0.03)
    assert fit.origin.roll_deg == pytest.approx(TRUTH.roll_deg, abs=0.1)
    assert fit.origin.pitch_deg == pytest.approx(TRUTH.pitch_deg, abs=0.1)
    assert estimate_origin(scan) == fit.origin
    # back in the sensor frame the points are where the generator put them (to the fit's precision)
    back = to_sensor_frame(scan[:, :3], fit.origin)
    orig = _first_scan(logs[0])
    assert np.percentile(np.linalg.norm(back - orig[:, :3], axis=1), 99) < 0.05


def test_the_sensor_estimated_from_a_moved_log_is_the_same(logs):
    moved = estimate_sensor(open_log(logs[1]), logs[1]).card
    spec = get_sensor("vlp32")
    truth = json.loads((logs[0] / "sequences/00/synth.json").read_text())["lidar"]
    assert moved.beams == spec.beams
    np.testing.assert_allclose(moved.elevations_deg, spec.elevations_deg, atol=0.02)
    np.testing.assert_allclose(moved.origin.xyz_m, TRUTH.xyz_m, atol=0.03)
    assert moved.mount_height_m == pytest.approx(truth["height"], abs=0.05)
    assert abs(moved.mount_roll_deg) < 0.3 and abs(moved.mount_pitch_deg) < 0.3  # level, from the sensor
    assert moved.azimuth_steps == spec.azimuth_steps
    assert moved.not_estimated == {}


def test_too_few_points_keep_the_log_origin():
    pts = np.random.default_rng(0).uniform(-3.0, 3.0, (40, 4))  # nothing 4–80 m away
    fit = fit_origin(pts)
    assert not fit.moved and fit.origin == SensorOrigin() and fit.sharpness == 0.0
