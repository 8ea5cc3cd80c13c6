"""Street styles: each is deterministic per seed, drawn in random mode, and produces its own ground
classes and objects."""

import json

import numpy as np
import pytest

from dsnet_core.errors import ConfigError
from dsnet_core.synth import generate_log
from dsnet_core.synth.config import SynthConfig
from dsnet_core.synth.log import child_seed, plan_sequence, sequence_seed
from dsnet_core.synth.render import Renderer
from dsnet_core.synth.road import PARKING, ROAD, SIDEWALK
from dsnet_core.synth.styles import STYLES
from dsnet_core.synth.styles.places import Junction
from dsnet_core.synth.variation import choose_setup

NEW_STYLES = sorted(set(STYLES) - {"classic"})


def _frame(style: str, seed: int = 0, sensor: str = "hdl64"):
    """(plan, raw semantic ids of the first sweep) of sequence 0 of ``style``."""
    setup = choose_setup(child_seed(sequence_seed(seed, 0), 2), style, sensor)
    plan = plan_sequence(seed, 0, 1, None, setup)
    scan, label = Renderer(plan.scene, setup.spec, plan.poses[:, :2, 3]).render(
        plan.poses[0], 0.0, np.random.default_rng(0)
    )
    return plan, scan, label & 0xFFFF


EXPECTED = {  # raw ids every sweep of the style shows (survey over seeds)
    "residential": {40, 44, 48, 50, 70, 72, 10},
    "arterial": {40, 60, 72, 50, 252},
    "downtown": {40, 48, 50, 11},
    "junction": {40, 48, 60},
    "parking_lot": {44, 60, 10},
    "country": {40, 49, 72},
}


@pytest.mark.parametrize("style", NEW_STYLES)
def test_style_shows_its_classes(style):
    plan, scan, sem = _frame(style)
    assert plan.scene.style == style and plan.scene.ground is not None
    present = set(np.unique(sem).tolist())
    assert EXPECTED[style] <= present, EXPECTED[style] - present
    assert 60_000 < scan.shape[0] <= 64 * 2048
    counts = {c: int((sem == c).sum()) for c in (40, 44, 48)}
    if style == "parking_lot":
        assert counts[44] > 5 * counts[40], "a parking lot is parking, not road"
    if style == "country":
        assert counts[48] == 0, "no sidewalks in the country"
    if style == "downtown":
        assert np.isin(sem, [30, 254]).any(), "people downtown"


def test_arterial_has_a_raised_median():
    plan, _, _ = _frame("arterial")
    g, road = plan.scene.ground, plan.scene.road
    x, y, _ = road.pose_at(np.arange(-20.0, 20.0), 0.0)
    i, j = g.cell(x, y)
    assert np.isin(g.cls[i, j], [72, SIDEWALK]).all() and g.raised[i, j].all()


def test_junction_has_a_cross_road():
    style = Junction()
    g = style.build(np.random.default_rng(0), 1.0, SynthConfig()).ground
    side = 1.0 if 0 in style.arms else -1.0
    u = 20.0  # metres out along the arm, on its centre line
    a = side * np.pi / 2 + style.angle
    i, j = g.cell(np.array(style.s_j + u * np.cos(a)), np.array(u * np.sin(a)))
    assert g.cls[i, j] in (ROAD, 60), "the cross road's carriageway reaches 20 m off the main road"
    i, j = g.cell(np.array(style.s_j - 30.0), np.array(side * 20.0))
    assert g.cls[i, j] not in (ROAD, PARKING), "and nowhere else"


def test_ground_is_graded_and_kerbed():
    plans = [_frame("residential", seed)[0] for seed in range(3)]
    kerbs = {round(p.scene.ground.kerb, 4) for p in plans}
    assert len(kerbs) == 3 and all(0.08 <= k <= 0.18 for k in kerbs), "kerbs of varied height"
    for p in plans:  # the ego stands on the surface at the drawn mounting height
        z = p.scene.ground.surface(p.poses[:, 0, 3], p.poses[:, 1, 3])
        np.testing.assert_allclose(p.poses[:, 2, 3] - z, p.setup.spec.height, atol=0.05)
    spans = [np.ptp(p.scene.ground.height) for p in plans]
    assert max(spans) > 1.0, "some streets climb"


@pytest.mark.parametrize("style", NEW_STYLES)
def test_style_deterministic_per_seed(tmp_path, style):
    a, b, c = tmp_path / "a", tmp_path / "b", tmp_path / "c"
    for root, seed in ((a, 0), (b, 0), (c, 1)):
        generate_log(root, frames=1, seed=seed, sensor="vlp16", style=style)
    for name in ("velodyne/000000.bin", "labels/000000.label", "poses.txt", "synth.json"):
        assert (a / "sequences/00" / name).read_bytes() == (b / "sequences/00" / name).read_bytes()
    assert (a / "sequences/00/velodyne/000000.bin").read_bytes() != (
        c / "sequences/00/velodyne/000000.bin"
    ).read_bytes()
    record = json.loads((a / "sequences/00/synth.json").read_text())
    assert record["style"] == style and record["sensor"] == "vlp16" and record["randomised"]


def test_random_mode_draws_every_style_and_records_it(tmp_path):
    drawn = {choose_setup(child_seed(sequence_seed(s, 0), 2), "random", "hdl64").style for s in range(60)}
    assert drawn == set(STYLES)
    generate_log(tmp_path, sequences=2, frames=1, seed=3, sensor="random", style="random")
    for name in ("00", "01"):
        record = json.loads((tmp_path / "sequences" / name / "synth.json").read_text())
        assert record["style"] in STYLES and record["sequence"] == name and record["seed"] == 3
        assert record["beams"] in (16, 32, 64, 128) and 1.5 <= record["lidar"]["height"] <= 2.2


def test_default_log_records_classic(tmp_path):
    generate_log(tmp_path, frames=1, sensor="vlp32")
    record = json.loads((tmp_path / "sequences/00/synth.json").read_text())
    assert (record["style"], record["sensor"], record["randomised"]) == ("classic", "vlp32", False)


def test_unknown_style(tmp_path):
    with pytest.raises(ConfigError, match="unknown street style 'suburb'"):
        generate_log(tmp_path, style="suburb")
