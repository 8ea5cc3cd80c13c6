"""Synthetic driving logs: realism invariants, pose conventions, determinism, ray-cast geometry."""

import math

import numpy as np
import pytest

from dsnet_core.errors import ConfigError, SequenceLayoutError
from dsnet_core.io.semantickitti import SemanticKittiReader
from dsnet_core.labels import load_label_map
from dsnet_core.synth import SENSORS, SynthConfig, generate_log, get_sensor, kitti_tr, plan_sequence
from dsnet_core.synth.primitives import BOX, CYLINDER, ELLIPSOID
from dsnet_core.synth.raycast import _intersect

LM = load_label_map("semantic-kitti")
FRAMES = 20  # the default of generate_log


@pytest.fixture(scope="module")
def hdl64_log(tmp_path_factory):
    """A default sequence: HDL-64, 20 frames, seed 0."""
    root = tmp_path_factory.mktemp("hdl64")
    assert generate_log(root) == ["00"]
    reader = SemanticKittiReader(root)
    frames = reader.frames("00")
    scans = [reader.scan(f) for f in frames]
    labels = [reader.labels(f) for f in frames]
    return reader, scans, labels


def _to_world(points: np.ndarray, pose: np.ndarray) -> np.ndarray:
    return points[:, :3] @ pose[:3, :3].T + pose[:3, 3]


def test_sensor_presets():
    hdl = get_sensor("hdl64")
    assert hdl.beams == 64 and hdl.azimuth_steps == 2048 and hdl.height == pytest.approx(1.73)
    assert max(hdl.elevations_deg) == pytest.approx(2.0) and min(hdl.elevations_deg) == pytest.approx(-24.9)
    assert get_sensor("vlp32").beams == 32 and get_sensor("vlp32").rays < hdl.rays
    dirs = hdl.directions()
    assert dirs.shape == (64 * 2048, 3)
    np.testing.assert_allclose(np.linalg.norm(dirs, axis=1), 1.0, atol=1e-12)
    with pytest.raises(ConfigError, match="unknown LiDAR model 'hdl32'; known: \\['hdl64', 'nuscenes32'"):
        get_sensor("hdl32")
    assert set(SENSORS) == {"hdl64", "vlp32", "nuscenes32", "ouster64", "ouster128", "vlp16"}


@pytest.mark.parametrize(
    ("kind", "half", "origin", "direction", "t", "cos"),
    [
        (BOX, (1.0, 1.0, 1.0), (-5.0, 0.0, 0.0), (1.0, 0.0, 0.0), 4.0, 1.0),
        (BOX, (2.0, 0.5, 1.0), (0.0, -3.0, 0.0), (0.0, 1.0, 0.0), 2.5, 1.0),
        (BOX, (1.0, 1.0, 1.0), (-5.0, 0.0, 3.0), (1.0, 0.0, 0.0), math.inf, 0.0),
        (CYLINDER, (0.5, 0.5, 2.0), (-5.0, 0.0, 0.0), (1.0, 0.0, 0.0), 4.5, 1.0),
        (CYLINDER, (0.5, 0.5, 2.0), (0.0, 0.0, 5.0), (0.0, 0.0, -1.0), 3.0, 1.0),
        (CYLINDER, (0.5, 0.5, 2.0), (-5.0, 0.3, 0.0), (1.0, 0.0, 0.0), 5.0 - 0.4, 0.8),
        (ELLIPSOID, (2.0, 1.0, 1.0), (-5.0, 0.0, 0.0), (1.0, 0.0, 0.0), 3.0, 1.0),
        (ELLIPSOID, (2.0, 1.0, 1.0), (0.0, 0.0, -4.0), (0.0, 0.0, 1.0), 3.0, 1.0),
        (ELLIPSOID, (2.0, 1.0, 1.0), (5.0, 0.0, 0.0), (1.0, 0.0, 0.0), math.inf, 0.0),
    ],
)
def test_primitive_intersections(kind, half, origin, direction, t, cos):
    got_t, got_cos = _intersect(kind, *origin, *direction, *half)
    assert got_t == pytest.approx(t)
    assert got_cos == pytest.approx(cos)


def test_points_per_scan_and_density_fall_with_range(hdl64_log):
    _, scans, _ = hdl64_log
    counts = [s.shape[0] for s in scans]
    assert 100_000 <= min(counts) and max(counts) <= 130_000, counts
    scan = np.concatenate(scans)
    r = np.linalg.norm(scan[:, :2], axis=1)
    edges = np.array([3.0, 6.0, 12.0, 24.0, 48.0, 96.0])
    per_m2 = np.histogram(r, edges)[0] / (np.pi * (edges[1:] ** 2 - edges[:-1] ** 2))
    assert (np.diff(per_m2) < 0).all(), per_m2
    assert per_m2[0] > 20 * per_m2[-1]
    assert r.max() <= get_sensor("hdl64").max_range + 0.2
    assert ((scan[:, 3] >= 0) & (scan[:, 3] <= 1)).all()


def test_every_thing_class_and_instance_ids(hdl64_log):
    _, _, labels = hdl64_log
    label = np.concatenate(labels)
    sem, inst = label & 0xFFFF, label >> 16
    train = LM.to_train(sem)
    assert set(np.unique(train[train > 0]).tolist()) >= set(LM.things)
    thing = LM.is_thing()[train]
    assert (inst[~thing] == 0).all(), "stuff points carry instance 0"
    assert (inst[thing] > 0).all(), "thing points carry an instance id"
    # an instance keeps one raw class over the whole sequence
    pairs = np.unique(np.stack([inst[thing], sem[thing]], axis=1), axis=0)
    assert len(np.unique(pairs[:, 0])) == len(pairs)
    assert np.isin([252, 253, 254], sem).all(), "moving things use the moving-* raw ids"
    assert np.isin([10, 11, 15, 30, 40, 48, 50, 60, 70, 71, 72, 80, 81], sem).all()


def test_remission_follows_material(hdl64_log):
    _, scans, labels = hdl64_log
    rem, sem = np.concatenate(scans)[:, 3], np.concatenate(labels) & 0xFFFF
    median = {c: float(np.median(rem[sem == c])) for c in (40, 60, 81)}
    assert median[60] > 2 * median[40], "lane markings are brighter than asphalt"
    assert median[81] > 0.5 and median[81] > median[60], "retro-reflective signs are brightest"


def test_parked_objects_stay_put_and_moving_ones_move(hdl64_log):
    reader, scans, labels = hdl64_log
    poses = reader.poses("00")
    np.testing.assert_allclose(poses[0], np.eye(4), atol=1e-9)
    plan = plan_sequence(0, 0, FRAMES)
    things = plan.scene.things
    seen: dict[int, int] = {}
    for label in labels:
        for i in np.unique(label >> 16):
            seen[int(i)] = seen.get(int(i), 0) + 1
    parked = [i for i, n in seen.items() if i and n == FRAMES and not things[i][1]]
    moving = [i for i, n in seen.items() if i and n == FRAMES and things[i][1]]
    assert len(parked) >= 5 and len(moving) >= 3
    static = plan.scene.static
    for inst in parked:
        parts = static.select(static.instance == inst)
        for scan, label, pose in zip(scans, labels, poses, strict=True):
            world = _to_world(scan[(label >> 16) == inst], plan.poses[0] @ pose)
            inside = np.zeros(len(world), dtype=bool)
            for c, yaw, half in zip(parts.center, parts.yaw, parts.half, strict=True):
                q = world - c
                local = np.stack(
                    [
                        np.cos(yaw) * q[:, 0] + np.sin(yaw) * q[:, 1],
                        -np.sin(yaw) * q[:, 0] + np.cos(yaw) * q[:, 1],
                        q[:, 2],
                    ],
                    axis=1,
                )
                inside |= (np.abs(local) <= np.asarray(half) + 0.1).all(axis=1)
            assert inside.all(), f"instance {inst}: {(~inside).sum()} points off the parked object"
    for inst in moving:
        first = _to_world(scans[0][(labels[0] >> 16) == inst], poses[0]).mean(axis=0)
        last = _to_world(scans[-1][(labels[-1] >> 16) == inst], poses[-1]).mean(axis=0)
        assert np.linalg.norm(first - last) > 0.8, f"moving instance {inst} did not move"


@pytest.mark.parametrize("seed", range(5))
def test_every_thing_class_is_placed_near_the_start(seed):
    scene = plan_sequence(seed, 3, 20).scene
    p = scene.primitives_at(0.0)
    ahead = p.instance[(p.instance > 0) & (np.abs(p.center[:, 0]) < 60) & (np.abs(p.center[:, 1]) < 60)]
    raw = {scene.things[int(i)][0] for i in ahead}
    assert set(LM.to_train(np.array(sorted(raw))).tolist()) >= set(LM.things)


def test_config_knobs_change_the_world():
    def count(**kw):  # (moving vehicles, walking people, parked cars)
        raw = [r for r, _ in plan_sequence(0, 0, 50, SynthConfig(**kw)).scene.things.values()]
        return sum(r in (252, 257, 258, 259) for r in raw), raw.count(254), raw.count(10)

    base = count()
    assert count(traffic=3.0)[0] > 2 * base[0]
    assert count(pedestrians=0.2)[1] < base[1] / 2
    assert count(parked=0.1)[2] < base[2] / 2
    poses = plan_sequence(0, 0, 50, SynthConfig(ego_speed=(3.0, 3.0))).poses
    step = np.linalg.norm(np.diff(poses[:, :2, 3], axis=0), axis=1)
    assert 0.2 < step.min() and step.max() < 0.4, "3 m/s ± a 1 m/s surge at 10 Hz"


def _footprints_overlap(a: np.ndarray, b: np.ndarray) -> bool:
    """Separating-axis test of two convex quadrilaterals ``(4, 2)``."""
    for poly in (a, b):
        for k in range(4):
            edge = poly[(k + 1) % 4] - poly[k]
            normal = np.array([-edge[1], edge[0]])
            pa, pb = a @ normal, b @ normal
            if pa.max() < pb.min() or pb.max() < pa.min():
                return False
    return True


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_things_never_interpenetrate(seed):
    """No two thing instances (parked or moving) share space at any time of a 10 s drive."""
    plan = plan_sequence(seed, 0, 100)
    for t in plan.times[::10]:
        p = plan.scene.primitives_at(t)
        p = p.select(p.instance > 0)
        c, s = np.cos(p.yaw), np.sin(p.yaw)
        corners = np.stack(
            [p.center[:, :2] + np.stack([c * p.half[:, 0] * sx - s * p.half[:, 1] * sy,
                                         s * p.half[:, 0] * sx + c * p.half[:, 1] * sy], axis=1)
             for sx, sy in ((1, 1), (1, -1), (-1, -1), (-1, 1))], axis=1,
        )  # fmt: skip
        reach = np.hypot(p.half[:, 0], p.half[:, 1])
        dist = np.linalg.norm(p.center[:, None, :2] - p.center[None, :, :2], axis=2)
        z_overlap = (
            np.abs(p.center[:, None, 2] - p.center[None, :, 2]) < p.half[:, None, 2] + p.half[None, :, 2]
        )
        near = (
            (dist < reach[:, None] + reach[None, :]) & z_overlap & (p.instance[:, None] < p.instance[None, :])
        )
        for i, j in zip(*np.nonzero(near), strict=True):
            assert not _footprints_overlap(corners[i], corners[j]), (
                f"t={t:.1f}s: instances {p.instance[i]} and {p.instance[j]} overlap"
            )


def test_ground_heights_in_world(hdl64_log):
    reader, scans, labels = hdl64_log
    plan = plan_sequence(0, 0, FRAMES)
    for scan, label, pose in zip(scans[::5], labels[::5], reader.poses("00")[::5], strict=True):
        z = _to_world(scan, plan.poses[0] @ pose)[:, 2]
        sem = label & 0xFFFF
        road = np.isin(sem, [40, 44, 60])
        assert np.abs(z[road]).max() < 0.1
        sidewalk = sem == 48
        assert np.median(z[sidewalk]) == pytest.approx(0.12, abs=0.02)


def test_deterministic_and_sequences_independent(tmp_path):
    a, b, c = tmp_path / "a", tmp_path / "b", tmp_path / "c"
    generate_log(a, sequences=2, frames=2, seed=3, sensor="vlp32")
    generate_log(b, sequences=1, frames=2, seed=3, sensor="vlp32", first_sequence=1)
    generate_log(c, sequences=1, frames=2, seed=4, sensor="vlp32")
    for name in ("velodyne/000001.bin", "labels/000001.label", "poses.txt", "calib.txt", "times.txt"):
        assert (a / "sequences/01" / name).read_bytes() == (b / "sequences/01" / name).read_bytes()
    scan = "velodyne/000000.bin"
    assert (a / "sequences/00" / scan).read_bytes() != (a / "sequences/01" / scan).read_bytes()
    assert (a / "sequences/00" / scan).read_bytes() != (c / "sequences/00" / scan).read_bytes()


def test_refuses_to_overwrite(tmp_path):
    generate_log(tmp_path, frames=1, sensor="vlp32")
    with pytest.raises(SequenceLayoutError, match=r"sequences/00: already holds a sequence"):
        generate_log(tmp_path, frames=1, sensor="vlp32")
    generate_log(tmp_path, frames=1, sensor="vlp32", seed=1, overwrite=True)
    assert len(SemanticKittiReader(tmp_path).frames("00")) == 1


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"frames": 0}, "need at least one sequence and one frame, got sequences=1, frames=0"),
        ({"sequences": 0}, "need at least one sequence and one frame, got sequences=0, frames=20"),
        ({"seed": -1}, "got seed=-1, first_sequence=0, sequences=1"),
        ({"first_sequence": 99, "sequences": 2}, "must end at 99 \\(two-digit names\\)"),
        ({"sensor": "hdl32"}, "unknown LiDAR model 'hdl32'"),
    ],
)
def test_bad_arguments(tmp_path, kwargs, message):
    with pytest.raises(ConfigError, match=message):
        generate_log(tmp_path, **kwargs)
    assert not (tmp_path / "sequences").exists()


def test_synth_log_fixture(synth_log):
    reader = SemanticKittiReader(synth_log)
    assert reader.sequences() == ["00", "01"]
    for seq in reader.sequences():
        frames = reader.frames(seq)
        assert len(frames) == 6
        poses = reader.poses(seq)
        assert poses.shape == (6, 4, 4)
        assert [reader.timestamp(f) for f in frames] == pytest.approx([0.1 * i for i in range(6)])
        tr = reader.seq_dir(seq) / "calib.txt"
        from dsnet_core.io import kitti

        np.testing.assert_allclose(kitti.read_calib(tr), kitti_tr(), atol=1e-9)
        for f in frames:
            scan = reader.scan(f)
            assert 20_000 < scan.shape[0] < get_sensor("vlp32").rays
            assert reader.labels(f).shape == (scan.shape[0],)
