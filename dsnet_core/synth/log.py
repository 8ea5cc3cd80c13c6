"""Writes synthetic driving logs in the SemanticKITTI layout (scans, labels, poses, calib, times)."""

from __future__ import annotations

import json
import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from dsnet_core.errors import ConfigError, SequenceLayoutError
from dsnet_core.io.semantickitti import write_frame, write_sequence_meta
from dsnet_core.sensor.card import SensorCard
from dsnet_core.synth.card_sensor import setup_from_card
from dsnet_core.synth.config import SynthConfig
from dsnet_core.synth.physics import apply_physics
from dsnet_core.synth.render import Renderer
from dsnet_core.synth.scene import Scene, build_scene
from dsnet_core.synth.sensor import get_sensor
from dsnet_core.synth.styles import build_styled_scene, check_style
from dsnet_core.synth.variation import SequenceSetup, apply_materials, check_sensor, choose_setup

log = logging.getLogger(__name__)
SETUP_FILE = "synth.json"  # per sequence: its style, sensor and draws (for held-out evaluations)

# Velodyne→camera transform of KITTI odometry sequence 00 (re-orthonormalised).
_KITTI_TR = np.array(
    [
        [4.276802385584e-04, -9.999672484946e-01, -8.084491683471e-03, -1.198459927713e-02],
        [-7.210626507497e-03, 8.081198471645e-03, -9.999413164504e-01, -5.403984729748e-02],
        [9.999738645903e-01, 4.859485810390e-04, -7.206933692422e-03, -2.921968648686e-01],
    ]
)


def kitti_tr() -> np.ndarray:
    """A realistic velodyne→camera ``Tr``, float64 ``(4, 4)``, exactly rigid."""
    u, _, vt = np.linalg.svd(_KITTI_TR[:, :3])
    tr = np.eye(4)
    tr[:3, :3] = u @ vt
    tr[:3, 3] = _KITTI_TR[:, 3]
    return tr


@dataclass(frozen=True)
class SequencePlan:
    """Everything needed to render a sequence.

    Attributes:
        scene: the world.
        poses: ``(F, 4, 4) float64`` sensor → scene-world poses.
        times: ``(F,) float64`` seconds from the first frame.
        setup: style, sensor and per-sequence draws (None: the legacy default of ``config.sensor``).
    """

    scene: Scene
    poses: np.ndarray
    times: np.ndarray
    setup: SequenceSetup | None = None


def sequence_seed(seed: int, index: int) -> np.random.SeedSequence:
    """The seed of sequence ``index`` (its number, e.g. 3 for "03") of a log made with ``seed``."""
    return np.random.SeedSequence([int(seed), int(index)])


def child_seed(ss: np.random.SeedSequence, k: int) -> np.random.SeedSequence:
    """Child ``k`` of ``ss`` (what ``ss.spawn(k + 1)[k]`` returns on a fresh ``ss``): 0 draws the world,
    1 the frames' noise, 2 the sequence's style, sensor and materials."""
    return np.random.SeedSequence(ss.entropy, spawn_key=(*ss.spawn_key, k), pool_size=ss.pool_size)


def plan_sequence(
    seed: int,
    index: int,
    frames: int,
    config: SynthConfig | None = None,
    setup: SequenceSetup | None = None,
) -> SequencePlan:
    """Build the world and the ego drive of sequence ``index`` (deterministic in ``seed, index``).

    Raises:
        ConfigError: the world holds more things than 16-bit instance ids can name.
    """
    return plan_from_seed(sequence_seed(seed, index), frames, config, setup, f"sequence {index:02d}")


def plan_from_seed(
    ss: np.random.SeedSequence,
    frames: int,
    config: SynthConfig | None = None,
    setup: SequenceSetup | None = None,
    name: str = "sequence",
) -> SequencePlan:
    """Build the world and the ego drive from a sequence seed (see :func:`plan_sequence`).

    Without ``setup`` (or with the legacy default) this is the classic street seen by
    ``config.sensor``; otherwise ``setup``'s style, sensor mounting and materials.
    """
    config = config or SynthConfig()
    legacy = setup is None or not setup.randomised
    spec = get_sensor(config.sensor) if setup is None else setup.spec
    rng = np.random.default_rng(child_seed(ss, 0))
    times = np.arange(frames, dtype=np.float64) * config.frame_period
    duration = float(times[-1]) if frames else 0.0
    if legacy:
        scene = build_scene(rng, duration, config)
    else:
        scene = apply_materials(build_styled_scene(setup.style, rng, duration, config), setup)
    if len(scene.things) > 0xFFFF:
        raise ConfigError(
            f"{name} would hold {len(scene.things)} things, more than 16-bit instance ids "
            "allow; use shorter sequences or less traffic"
        )
    poses = _ego_poses(scene, times, spec.height, config.jitter_deg, rng)
    if scene.ground is not None:  # stand on the road surface and pitch with its grade
        # math.atan2/atan (the C library's, as numpy's own loop uses on AVX2 CPUs and on strided
        # input): numpy's arctan2/arctan take other kernels on AVX-512 CPUs that differ in the last bit
        x, y = poses[:, 0, 3], poses[:, 1, 3]
        yaw = np.array([math.atan2(s, c) for s, c in zip(poses[:, 1, 0], poses[:, 0, 0], strict=True)])
        ahead = scene.ground.surface(x + np.cos(yaw), y + np.sin(yaw))
        behind = scene.ground.surface(x - np.cos(yaw), y - np.sin(yaw))
        poses[:, 2, 3] += scene.ground.surface(x, y)
        pitch = -np.array([math.atan(g) for g in (ahead - behind) / 2.0])
        c, s = np.cos(pitch), np.sin(pitch)
        tilt = np.zeros((frames, 3, 3))
        tilt[:, 0, 0], tilt[:, 0, 2], tilt[:, 1, 1], tilt[:, 2, 0], tilt[:, 2, 2] = c, s, 1.0, -s, c
        poses[:, :3, :3] = poses[:, :3, :3] @ tilt
    if not legacy:
        poses = poses @ setup.mount()
    return SequencePlan(scene, poses, times, setup)


def _ego_poses(scene: Scene, times: np.ndarray, height: float, jitter_deg: float, rng) -> np.ndarray:
    phase = rng.uniform(0, 2 * np.pi, 3)
    sway = 0.15 * np.sin(2 * np.pi * times / 7.0 + phase[0])
    x, y, yaw = scene.road.pose_at(scene.ego_s(times), scene.ego_d + sway)
    amp = np.deg2rad(jitter_deg)
    pitch = amp * np.sin(2 * np.pi * times / 1.3 + phase[1])
    roll = amp * np.sin(2 * np.pi * times / 1.9 + phase[2])
    cy, sy, cp, sp, cr, sr = (
        np.cos(yaw),
        np.sin(yaw),
        np.cos(pitch),
        np.sin(pitch),
        np.cos(roll),
        np.sin(roll),
    )
    poses = np.zeros((times.size, 4, 4))
    poses[:, 0] = np.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr, x], axis=1)
    poses[:, 1] = np.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr, y], axis=1)
    poses[:, 2] = np.stack([-sp, cp * sr, cp * cr, np.full_like(x, height)], axis=1)
    poses[:, 3, 3] = 1.0
    return poses


def generate_log(
    out_root: Path,
    sequences: int = 1,
    frames: int = 20,
    seed: int = 0,
    sensor: str = "hdl64",
    first_sequence: int = 0,
    config: SynthConfig | None = None,
    on_frame: Callable[[str, int], None] | None = None,
    overwrite: bool = False,
    style: str = "classic",
    styles: list[str] | tuple[str, ...] | None = None,
    sensors: list[str] | tuple[str, ...] | None = None,
    physics: dict[str, Any] | None = None,
    sensor_card: SensorCard | None = None,
) -> list[str]:
    """Generate ``sequences`` synthetic sequences of ``frames`` sweeps under ``out_root/sequences/``.

    Sequence k is named ``f"{first_sequence + k:02d}"`` and depends only on ``(seed, its number)``.
    Poses are written in the camera frame with a KITTI ``Tr``, relative to the first frame (the
    first LiDAR pose is the identity, as in KITTI).

    Args:
        out_root: log root (created if missing).
        sequences: number of sequences.
        frames: sweeps per sequence (10 Hz).
        seed: master seed.
        sensor: a LiDAR preset (:data:`SENSORS`) or ``random`` (drawn per sequence).
        first_sequence: number of the first sequence.
        config: world knobs; its ``sensor`` is replaced by ``sensor``.
        on_frame: called with (sequence, frame index) after each frame is written.
        overwrite: replace sequences that already exist (their scans and labels are deleted first).
        style: street style (:data:`styles.STYLES`) or ``random`` (drawn per sequence). Anything but
            ``classic`` with ``hdl64``/``vlp32`` also draws the sensor's mounting, noise and the
            remission per sequence; each sequence's choices are written to ``synth.json`` beside it.
        styles, sensors: what ``random`` draws from (default: all).
        physics: deliberately altered sensor physics (:func:`~dsnet_core.synth.physics.parse_physics`
            keys: beam pattern, mounting height, remission model, ray drop), applied after each
            sequence's own draws and recorded in its ``synth.json``.
        sensor_card: render with this sensor (:mod:`dsnet_core.synth.card_sensor`) instead of
            ``sensor``: its beams, azimuth grid, field of view, mounting, range limits, ray drop,
            range noise, remission and frame period; recorded in ``synth.json``.

    Returns:
        The sequence names written.

    Raises:
        SequenceLayoutError: a sequence folder already holds files and ``overwrite`` is False.
        ConfigError: unknown ``sensor`` or ``style``; fewer than one sequence or frame; a negative seed;
            sequence numbers beyond 99 (names are two digits); ``physics`` with a sensor card.
    """
    if sequences < 1 or frames < 1:
        raise ConfigError(
            f"need at least one sequence and one frame, got sequences={sequences}, frames={frames}"
        )
    if seed < 0 or first_sequence < 0 or first_sequence + sequences > 100:
        raise ConfigError(
            f"seed and sequence numbers must be ≥ 0 and sequences must end at 99 (two-digit names), got "
            f"seed={seed}, first_sequence={first_sequence}, sequences={sequences}"
        )
    check_sensor(sensor)
    check_style(style)
    config = replace(config or SynthConfig(), sensor=sensor)
    if sensor_card is not None:
        if physics:
            raise ConfigError("a sensor card fixes the sensor: give it or --physics, not both")
        if sensor_card.frame_period_s is not None:
            config = replace(config, frame_period=sensor_card.frame_period_s)
    tr = kitti_tr()
    names = [f"{first_sequence + k:02d}" for k in range(sequences)]
    for name in names:
        _prepare(Path(out_root) / "sequences" / name, overwrite)
    for name in names:
        index = int(name)
        seq_dir = Path(out_root) / "sequences" / name
        setup = choose_setup(child_seed(sequence_seed(seed, index), 2), style, sensor, styles, sensors)
        if sensor_card is not None:
            setup = setup_from_card(sensor_card, setup.style)
        setup = replace(setup, spec=apply_physics(setup.spec, physics))
        plan = plan_sequence(seed, index, frames, config, setup)
        renderer = Renderer(plan.scene, setup.spec, plan.poses[:, :2, 3])
        frame_seeds = sequence_seed(seed, index).spawn(2)[1].spawn(frames)
        for i in range(frames):
            scan, label = renderer.render(
                plan.poses[i], float(plan.times[i]), np.random.default_rng(frame_seeds[i])
            )
            write_frame(seq_dir, f"{i:06d}", scan, label)
            if on_frame is not None:
                on_frame(name, i)
        relative = np.linalg.inv(plan.poses[0])[None] @ plan.poses
        write_sequence_meta(seq_dir, relative, tr, plan.times)
        record = {
            "sequence": name,
            "seed": int(seed),
            **setup.record(),
            **({"physics": physics} if physics else {}),
            **({"sensor_card": sensor_card.model_dump(mode="json")} if sensor_card is not None else {}),
        }
        if config.variety != "base" and setup.style != "classic":
            record["variety"] = config.variety
        (seq_dir / SETUP_FILE).write_text(json.dumps(record, indent=1, sort_keys=True) + "\n")
        log.info("wrote %s (%d frames, %s street, %s)", seq_dir, frames, setup.style, setup.sensor)
    return names


def _prepare(seq_dir: Path, overwrite: bool) -> None:
    if not seq_dir.exists() or not any(seq_dir.iterdir()):
        return
    if not overwrite:
        raise SequenceLayoutError(
            seq_dir, "already holds a sequence; choose another folder or overwrite it (--overwrite)"
        )
    for pattern in ("velodyne/*.bin", "labels/*.label", "poses.txt", "calib.txt", "times.txt", SETUP_FILE):
        for path in seq_dir.glob(pattern):
            path.unlink()
