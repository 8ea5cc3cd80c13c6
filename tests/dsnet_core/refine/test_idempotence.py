"""Refining refined labels changes (almost) nothing."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from dsnet_core.refine import RefineParams, VoteParams, refine_sequence
from tests.dsnet_core.refine import scenes


@pytest.mark.parametrize("soft", [False, True])
def test_refining_refined_labels_changes_at_most_a_thousandth_of_the_points(soft):
    street = scenes.sequence(30, density=2)
    noisy, masks = scenes.add_static_noise(street, 0.2)
    frames = []
    for f in noisy:  # a track cut in two, and a track with a flipped class, for the track steps
        f = replace(f, inst=np.where((f.inst == 2) & (f.index > 15), 8, f.inst))
        if f.index % 4 == 0:
            f = replace(f, sem=np.where(f.inst == 1, scenes.TRUCK, f.sem))
        frames.append(scenes.soft_probs(f) if soft else f)
    params = RefineParams(vote=VoteParams(voxel=0.4))
    once = refine_sequence(frames, scenes.SETS, params)
    assert sum(o.change.changed for o in once) > 0.1 * sum(m.sum() for m in masks)
    again = refine_sequence(
        [replace(f, sem=o.sem, inst=o.inst) for f, o in zip(frames, once, strict=True)], scenes.SETS, params
    )
    changed = sum(a.change.changed for a in again)
    assert changed <= 0.001 * sum(f.n_points for f in frames), changed
