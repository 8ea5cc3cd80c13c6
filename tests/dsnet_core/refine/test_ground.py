"""The ground prior: corrections by a ground segmentation, and Patchwork++ as an optional extra."""

from __future__ import annotations

import sys
from dataclasses import replace

import numpy as np
import pytest

from dsnet_core.errors import MissingExtraError
from dsnet_core.refine import ClassSets, GroundParams, RefineParams, refine_sequence
from dsnet_core.refine.ground import GROUND, NON_GROUND, UNKNOWN, Patchwork, ground_correction
from tests.dsnet_core.refine import scenes


def _probs(rows: list[dict[int, float]]) -> np.ndarray:
    p = np.zeros((len(rows), scenes.LM.num_classes))
    for i, r in enumerate(rows):
        for c, v in r.items():
            p[i, c] = v
    return np.rint(p * 255).astype(np.uint8)


def test_low_confidence_points_move_to_the_most_probable_class_of_the_other_group():
    sem = np.array([scenes.BUILDING, scenes.BUILDING, scenes.ROAD, scenes.ROAD, scenes.ROAD, scenes.CAR])
    inst = np.array([0, 0, 0, 0, 0, 4])
    probs = _probs(
        [
            {scenes.BUILDING: 0.5, scenes.SIDEWALK: 0.3, scenes.ROAD: 0.2},  # -> sidewalk
            {scenes.BUILDING: 0.9, scenes.ROAD: 0.1},  # sure of itself: stays
            {scenes.ROAD: 0.4, scenes.CAR: 0.35, scenes.POLE: 0.25},  # -> pole (no thing without an id)
            {scenes.ROAD: 0.4, scenes.POLE: 0.6},  # segmenter unsure: stays
            {scenes.ROAD: 0.5, scenes.POLE: 0.5},  # agrees with the segmenter: stays
            {scenes.CAR: 0.3, scenes.ROAD: 0.7},  # has an id: its track decides
        ]
    )
    verdict = np.array([GROUND, GROUND, NON_GROUND, UNKNOWN, GROUND, GROUND], np.int8)
    out, changed = ground_correction(sem, inst, probs, verdict, scenes.SETS, max_confidence=0.6)
    assert out.tolist() == [
        scenes.SIDEWALK,
        scenes.BUILDING,
        scenes.POLE,
        scenes.ROAD,
        scenes.ROAD,
        scenes.CAR,
    ]
    assert changed.tolist() == [True, False, True, False, False, False]
    frozen = np.array([True, False, False, False, False, False])
    assert ground_correction(sem, inst, probs, verdict, scenes.SETS, 0.6, frozen)[0][0] == scenes.BUILDING


class HeightGround:
    """A stand-in segmenter: ground below 1.5 m under the sensor (the test street is flat)."""

    def __call__(self, xyz, intensity):
        return np.where(xyz[:, 2] < -1.45, GROUND, NON_GROUND).astype(np.int8)


def test_refine_applies_the_ground_prior_to_unsure_points_only():
    street = scenes.sequence(6)
    frames = []
    for f in street:
        f = scenes.soft_probs(f, sharpness=0.8)
        rng = np.random.default_rng(f.index)
        wrong = (f.sem == scenes.ROAD) & (rng.random(f.n_points) < 0.1)
        probs = f.probs.copy()
        probs[wrong] = _probs([{scenes.BUILDING: 0.45, scenes.ROAD: 0.4, scenes.CAR: 0.15}])
        frames.append(replace(f, sem=np.where(wrong, scenes.BUILDING, f.sem), probs=probs))
    params = RefineParams(ground=GroundParams(enabled=True))
    params = replace(params, vote=replace(params.vote, enabled=False))
    out = refine_sequence(frames, scenes.SETS, params, ground=HeightGround())
    for o, f, g in zip(out, frames, street, strict=True):
        np.testing.assert_array_equal(o.sem, g.sem)  # every wrong road point is road again
        assert o.change.by_ground == int((f.sem != g.sem).sum()) > 0
        assert o.change.transitions == {(scenes.BUILDING, scenes.ROAD): o.change.by_ground}


def test_the_ground_prior_needs_a_segmenter_and_ground_classes():
    frames = [scenes.soft_probs(f) for f in scenes.sequence(3)]
    params = RefineParams(ground=GroundParams(enabled=True))
    with pytest.raises(ValueError, match="ground segmenter"):
        refine_sequence(frames, scenes.SETS, params)
    no_ground = ClassSets(**{**scenes.SETS.__dict__, "ground": np.zeros(scenes.LM.num_classes, bool)})
    with pytest.raises(ValueError, match="declares ground classes"):
        refine_sequence(frames, no_ground, params, ground=HeightGround())


def test_without_pypatchworkpp_the_error_names_the_pip_install(monkeypatch):
    monkeypatch.setitem(sys.modules, "pypatchworkpp", None)  # as if the extra were not installed
    with pytest.raises(MissingExtraError, match=r"pypatchworkpp.*pip install 'dsnet-pipeline\[ground\]'"):
        Patchwork()


def test_patchwork_separates_a_flat_road_from_what_stands_on_it():
    pytest.importorskip("pypatchworkpp", reason="the optional extra: pip install 'dsnet-pipeline[ground]'")
    f = scenes.frame(3, density=3)
    verdict = Patchwork(sensor_height=scenes.HEIGHT)(f.xyz, f.xyz[:, 0] * 0)
    assert (verdict[f.sem == scenes.ROAD] == GROUND).mean() > 0.9  # measured 0.95
    upright = np.isin(f.sem, [scenes.CAR, scenes.PERSON, scenes.BUILDING, scenes.POLE])
    assert (verdict[upright] == NON_GROUND).mean() > 0.95  # measured 0.99
