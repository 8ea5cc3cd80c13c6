"""The ``wide`` variety (issue #32): what it widens, and that base streets do not change."""

import json

import numpy as np
import pytest

from dsnet_core.errors import ConfigError
from dsnet_core.synth import generate_log
from dsnet_core.synth.config import SynthConfig
from dsnet_core.synth.layout import BUILDING, FENCE, TRUNK
from dsnet_core.synth.log import child_seed, plan_sequence, sequence_seed
from dsnet_core.synth.primitives import BOX, CYLINDER, Part
from dsnet_core.synth.render import Renderer
from dsnet_core.synth.road import ROAD, SIDEWALK, TERRAIN
from dsnet_core.synth.stream import StreamOptions
from dsnet_core.synth.styles.wide import FenceRun, Wide, car, facade, other_vehicle
from dsnet_core.synth.surface import MAX_SHIFT, Lattice, Surface
from dsnet_core.synth.variation import choose_setup
from dsnet_core.train.stream import StreamLog

WIDE = SynthConfig(variety="wide")


def _plan(style: str, config: SynthConfig | None, seed: int = 3, sensor: str = "vlp16"):
    setup = choose_setup(child_seed(sequence_seed(seed, 0), 2), style, sensor)
    return setup, plan_sequence(seed, 0, 1, config, setup)


def _wide(seed: int = 0, **kw) -> Wide:
    w = Wide.draw(np.random.default_rng(seed))
    for k, v in kw.items():
        setattr(w, k, v)
    return w


def test_unknown_variety_is_one_config_error():
    with pytest.raises(ConfigError, match="unknown synth variety 'narrow'; choose base or wide"):
        SynthConfig(variety="narrow")


def test_base_streets_draw_the_same_world_with_or_without_the_knob():
    _, a = _plan("residential", None)
    _, b = _plan("residential", SynthConfig(variety="base"))
    assert np.array_equal(a.scene.static.center, b.scene.static.center)
    assert a.scene.surface is None and b.scene.surface is None


def test_wide_draws_leave_the_street_generator_where_it_was():
    rng = np.random.default_rng(7)
    Wide.draw(rng)
    assert rng.random() == np.random.default_rng(7).random()


def test_classic_street_ignores_the_variety():
    _, a = _plan("classic", None, sensor="hdl64")
    _, b = _plan("classic", WIDE, sensor="hdl64")
    assert np.array_equal(a.scene.static.center, b.scene.static.center) and b.scene.surface is None


WIDENED = {  # what every style's wide streets show over four seeds
    "residential": {"low", "tall_fence", "bark", "textured"},
    "downtown": {"low", "bark", "textured"},  # no fences downtown
    "country": {"tall_fence", "bark"},
    "arterial": {"low", "bark", "textured"},
}


@pytest.mark.parametrize("style", sorted(WIDENED))
def test_wide_streets_hold_low_buildings_tall_fences_and_barked_trunks(style):
    found = set()
    for seed in range(4):
        _, plan = _plan(style, WIDE, seed)
        assert plan.scene.surface is not None
        p = plan.scene.static
        height = p.center[:, 2] + p.half[:, 2] - plan.scene.ground.height_at(p.center[:, 0], p.center[:, 1])
        building, trunks = p.semantic == BUILDING, p.semantic == TRUNK
        if ((p.semantic == FENCE) & (height > 2.05)).any():
            found.add("tall_fence")
        if (building & (p.half[:, 2] < 0.5)).any():  # floor bands
            found.add("textured")
        if (building & (height < 3.45) & (height > 2.1) & (p.center[:, 2] - p.half[:, 2] < 0.5)).any():
            found.add("low")
        trees = len(np.unique(np.round(p.center[trunks, :2]), axis=0))
        if trunks.sum() >= 2 * max(trees, 1):  # pieces of bark, not one cylinder per tree
            found.add("bark")
    assert WIDENED[style] <= found, WIDENED[style] - found


def test_facade_is_a_recessed_core_behind_piers_and_bands():
    wall = Part(BOX, (0.0, 0.0, 6.0), (10.0, 5.0, 6.0), 0.4)
    parts = facade(np.random.default_rng(1), wall)
    core, rest = parts[0], parts[1:]
    assert core.reflectivity <= 0.2 and core.half[2] == 6.0
    recess = wall.half[1] - core.half[1]
    assert 0.15 <= recess <= 0.45 and np.isclose(wall.half[0] - core.half[0], recess)
    for p in rest:  # inside the wall's box, balconies aside
        assert p.center[2] - p.half[2] >= -1e-9 and p.center[2] + p.half[2] <= 12.0 + 1e-9
        assert abs(p.center[0]) + p.half[0] <= 10.0 + 1e-9
    assert sum(p.half[1] == 5.0 and p.half[0] < 1.0 for p in rest) >= 3  # piers


def test_low_buildings_take_their_roof_down_with_them():
    walls = Part(BOX, (0.0, 0.0, 3.0), (5.0, 4.0, 3.0), 0.3)
    roof = Part(BOX, (0.0, 0.0, 6.6), (5.0, 3.0, 0.6), 0.2)
    out = _wide(low=1.0, textured=0.0).building([walls, roof])
    wall, top = out
    h = 2 * wall.half[2]
    assert 2.2 <= h <= 3.4 and np.isclose(top.center[2], 6.6 - (6.0 - h))


def test_fence_runs_share_their_posts_across_pieces():
    run = FenceRun("railing", 0.0, 1.5, 0.05, 2.0, 3, 0.4)
    posts = []
    for sc in (4.0, 12.0):
        parts = run.piece(sc, 4.0)
        posts += [sc + p.center[0] for p in parts if p.half[0] == 0.05]
        rails = [p for p in parts if p.half[0] > 1.0]
        assert len(rails) == 3 and all(0.0 < p.center[2] < 1.5 for p in rails)
    assert np.allclose(np.diff(sorted(posts)), 2.0)
    assert run.piece(0.0, 4.0)[0].center[2] == 0.75
    solid = FenceRun("wall", 0.0, 2.4, 0.3, 2.0, 0, 0.4).piece(0.0, 4.0)
    assert len(solid) == 1 and solid[0].half[1] == 0.15 and solid[0].half[2] == 1.2


def test_trunks_lean_and_vary_but_keep_their_height():
    trunk = [Part(CYLINDER, (0.0, 0.0, 1.5), (0.2, 0.2, 1.5), 0.3)]
    parts = _wide(3).trunk(trunk)
    assert len(parts) == 6 and all(p.kind == CYLINDER for p in parts)
    assert all(0.16 <= p.half[0] <= 0.24 for p in parts)
    assert np.isclose(parts[-1].center[2] + parts[-1].half[2], 3.0 + 0.02)
    assert max(np.hypot(*p.center[:2]) for p in parts) < 0.5


def test_vans_are_cars_and_other_vehicles_are_caravans_trailers_tractors():
    rng = np.random.default_rng(0)
    heights = [car(rng).height for _ in range(300)]
    assert max(heights) > 1.95 > min(heights)  # vans among the cars
    others = [other_vehicle(rng) for _ in range(60)]
    assert min(o.height for o in others) < 1.3 and max(o.height for o in others) > 2.5


def _surface(grass=0.2, undulation=0.1) -> Surface:
    rng = np.random.default_rng(0)
    lo, hi = np.array([-50.0, -50.0]), np.array([50.0, 50.0])
    patchiness = np.zeros(256)
    patchiness[[ROAD, TERRAIN]] = 0.4
    return Surface(
        grass, undulation, Lattice.draw(rng, lo, hi, 3.0), Lattice.draw(rng, lo, hi, 2.0), patchiness
    )


def test_grass_moves_terrain_hits_only_and_at_most_max_shift():
    n = 2000
    rng = np.random.default_rng(1)
    az = rng.uniform(0, 2 * np.pi, n)
    el = np.deg2rad(rng.uniform(-25, -1, n))
    dirs = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=1)
    origin = np.array([0.0, 0.0, 1.8])
    t = 1.8 / -dirs[:, 2]
    cls = np.where(np.arange(n) % 2 == 0, TERRAIN, SIDEWALK).astype(np.int32)
    cls[:10] = TERRAIN
    t[:10] = np.inf
    t2, _, _ = _surface().roughen(origin, dirs, (t, cls, np.ones(n)), np.random.default_rng(0))
    moved = t2 != t
    assert not moved[cls != TERRAIN].any() and np.isinf(t2[:10]).all()
    fin = np.isfinite(t)
    shift = t[fin] - t2[fin]
    assert np.abs(shift).max() <= MAX_SHIFT + 1e-9 and moved.sum() > 0.4 * n
    flat, *_ = _surface(0.0, 0.0).roughen(origin, dirs, (t, cls, np.ones(n)), np.random.default_rng(0))
    assert np.array_equal(flat, t)


def test_patches_scale_ground_remission_only():
    n = 500
    dirs = np.tile([[1.0, 0.0, 0.0]], (n, 1))
    t = np.linspace(1.0, 40.0, n)
    sem = np.where(np.arange(n) % 2 == 0, ROAD, BUILDING).astype(np.int32)
    refl = np.full(n, 0.3)
    out = _surface().patch(np.zeros(3), dirs, t, sem, refl)
    assert np.array_equal(out[sem == BUILDING], refl[sem == BUILDING])
    road = out[sem == ROAD]
    assert (
        road.std() > 0.01 and (0.3 * np.exp(-0.4) - 1e-9 <= road).all() and (road <= 0.3 * np.exp(0.4)).all()
    )


def test_a_wide_log_records_its_variety_and_renders(tmp_path):
    generate_log(tmp_path, sequences=1, frames=1, seed=2, sensor="vlp16", style="residential", config=WIDE)
    record = json.loads((tmp_path / "sequences/00/synth.json").read_text())
    assert record["variety"] == "wide"
    setup, plan = _plan("residential", WIDE, 2)
    scan, label = Renderer(plan.scene, setup.spec, plan.poses[:, :2, 3]).render(
        plan.poses[0], 0.0, np.random.default_rng(0)
    )
    assert len(scan) > 10_000 and (np.asarray(label) & 0xFFFF == TERRAIN).any()


def test_stream_record_names_a_wide_variety_only():
    base = StreamLog(0, StreamOptions(frames=1), 4)
    wide = StreamLog(0, StreamOptions(frames=1, config=WIDE), 4)
    assert "variety" not in base.record() and wide.record()["variety"] == "wide"
    assert base.fingerprint() != wide.fingerprint()
