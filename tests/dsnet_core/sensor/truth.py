"""What a ``dsnet synth`` log's sensor really did: its realised ray-drop rate (of the rays that hit a
surface within range, the share the simulation dropped), recomputed from the generator's own draws."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from dsnet_core.synth.config import SynthConfig
from dsnet_core.synth.log import child_seed, plan_sequence, sequence_seed
from dsnet_core.synth.render import Renderer
from dsnet_core.synth.variation import choose_setup


def realised_drop(sensor: str, frames: int, seed: int = 0, index: int = 0) -> float:
    """The ray-drop rate of sequence ``index`` of ``generate_log(..., frames, seed, sensor)``."""
    config = replace(SynthConfig(), sensor=sensor)
    setup = choose_setup(child_seed(sequence_seed(seed, index), 2), "classic", sensor)
    plan = plan_sequence(seed, index, frames, config, setup)
    renderer = Renderer(plan.scene, setup.spec, plan.poses[:, :2, 3])
    frame_seeds = sequence_seed(seed, index).spawn(2)[1].spawn(frames)
    hits = returns = 0
    spec = setup.spec
    for i in range(frames):
        rng = np.random.default_rng(frame_seeds[i])
        hit_range, *_ = renderer.cast(
            plan.poses[i], float(plan.times[i]), float(rng.uniform(0.0, 1000.0)), rng
        )
        hits += int(((hit_range >= spec.min_range) & (hit_range <= spec.max_range)).sum())
        scan, _ = renderer.render(plan.poses[i], float(plan.times[i]), np.random.default_rng(frame_seeds[i]))
        returns += scan.shape[0]
    return 1.0 - returns / hits
