"""Static-world voting: noise on static points is voted away, the windowed vote equals a direct
whole-sequence vote, and the result of a frame does not depend on how frames are split in blocks."""

from __future__ import annotations

import tracemalloc
from dataclasses import replace

import numpy as np
import pytest

from dsnet_core.refine import RefineParams, VoteParams, plan_refinement, refine_block, refine_sequence
from dsnet_core.refine.frame import FULL_VOTE, Confidence, FrameInput, range_weights
from dsnet_core.refine.voxels import VoxelGrid, frame_votes, window_consensus
from tests.dsnet_core.refine import scenes

PARAMS = RefineParams(vote=VoteParams(voxel=0.4))


@pytest.fixture(scope="module")
def street():
    return scenes.sequence(30, density=3)


def test_noise_on_a_fifth_of_the_static_points_is_voted_away(street):
    noisy, masks = scenes.add_static_noise(street, 0.2)
    out = refine_sequence(noisy, scenes.SETS, PARAMS)
    noised = sum(int(m.sum()) for m in masks)
    restored = sum(int((o.sem[m] == g.sem[m]).sum()) for o, g, m in zip(out, street, masks, strict=True))
    assert restored / noised >= 0.95  # measured 0.990
    # clean points stay as they were, ids everywhere too
    broken = sum(int((o.sem[~m] != g.sem[~m]).sum()) for o, g, m in zip(out, street, masks, strict=True))
    assert broken / sum(f.n_points for f in street) < 0.001
    assert all(np.array_equal(o.inst, g.inst) for o, g in zip(out, street, strict=True))
    # the change record counts what happened
    c = out[15].change
    assert c.changed == c.class_changed == c.by_static + c.by_track and c.id_changed == 0
    assert c.class_changed == sum(c.transitions.values())
    assert c.class_changed == int((noisy[15].sem != out[15].sem).sum())


def test_soft_probabilities_vote_the_same_way(street):
    noisy, masks = scenes.add_static_noise(street, 0.2)
    soft = [scenes.soft_probs(f) for f in noisy]
    out = refine_sequence(soft, scenes.SETS, PARAMS)
    noised = sum(int(m.sum()) for m in masks)
    restored = sum(int((o.sem[m] == g.sem[m]).sum()) for o, g, m in zip(out, street, masks, strict=True))
    assert restored / noised >= 0.95


def _reference(frames: list[FrameInput], params: RefineParams) -> list[np.ndarray]:
    """The whole-sequence vote computed directly: every voter of every frame into one table."""
    sets, v = scenes.SETS, params.vote
    plan = plan_refinement(frames, sets, params)
    grid = VoxelGrid(v.voxel, plan.origin)
    keys, classes, values, frame_of = [], [], [], []
    for f in frames:
        voter = sets.stuff[f.sem] & (f.inst == 0) | (f.inst == 1)  # stuff, and the parked car
        sem = np.where(f.inst == 1, scenes.CAR, f.sem)
        keys.append(grid.keys(f.world()[voter]))
        classes.append(sem[voter])
        values.append(255 * range_weights(f, v.range_ref)[voter] * 255)
        frame_of.append(np.full(int(voter.sum()), f.index))
    keys, classes, values, frame_of = map(np.concatenate, (keys, classes, values, frame_of))
    uniq, inv = np.unique(keys, return_inverse=True)
    table = np.zeros((uniq.size, sets.num_classes), np.int64)
    np.add.at(table, (inv, classes), values)
    seen = np.zeros(uniq.size, np.int64)
    pairs = np.unique(inv * 1000 + frame_of)
    np.add.at(seen, pairs // 1000, 1)
    out = []
    for f in frames:
        sem = np.where(f.inst == 1, scenes.CAR, f.sem)
        taker = (f.inst == 0) & ~sets.ignore[sem]
        pos = np.searchsorted(uniq, grid.keys(f.world()[taker]))
        pos = np.minimum(pos, uniq.size - 1)
        found = uniq[pos] == grid.keys(f.world()[taker])
        t = table[pos]
        total = t.sum(axis=1)
        best = t.argmax(axis=1)
        ok = found & (seen[pos] >= v.min_frames) & (t.max(axis=1) >= v.min_share * total)
        ok &= total / FULL_VOTE >= v.min_votes
        ok &= sets.stuff[best]
        new = sem.copy()
        idx = np.flatnonzero(taker)
        new[idx[ok]] = best[ok]
        out.append(new)
    return out


def test_a_window_longer_than_the_sequence_is_the_whole_sequence_vote():
    frames, _ = scenes.add_static_noise(scenes.sequence(12, density=2), 0.2)
    params = replace(PARAMS, vote=replace(PARAMS.vote, window=12, top_k=scenes.LM.num_classes))
    out = refine_sequence(frames, scenes.SETS, params)
    ref = _reference(frames, params)
    for o, r in zip(out, ref, strict=True):
        np.testing.assert_array_equal(o.sem, r)


@pytest.mark.parametrize(
    "blocks", [[range(0, 7), range(7, 14), range(14, 20)], [[19], [3, 4], [0], [8, 9, 10]]]
)
def test_a_frame_is_refined_the_same_whatever_block_it_is_in(blocks):
    frames, _ = scenes.add_static_noise(scenes.sequence(20, density=2), 0.2)
    params = replace(PARAMS, vote=replace(PARAMS.vote, window=4))
    whole = {r.index: r for r in refine_sequence(frames, scenes.SETS, params)}
    plan = plan_refinement(frames, scenes.SETS, params)
    for block in blocks:
        loaded: list[int] = []

        def load(i: int, loaded: list[int] = loaded) -> FrameInput:
            loaded.append(i)
            return frames[i]

        got = list(refine_block(load, list(block), plan, scenes.SETS, params))
        assert [r.index for r in got] == sorted(block)
        for r in got:
            np.testing.assert_array_equal(r.sem, whole[r.index].sem)
            np.testing.assert_array_equal(r.inst, whole[r.index].inst)
            assert r.change == whole[r.index].change
        # each needed frame read once, and only the frames within ±W of the block
        assert loaded == [i for i in range(20) if min(block) - 4 <= i <= max(block) + 4]


def _peak_bytes(n_frames: int) -> int:
    params = replace(PARAMS, vote=replace(PARAMS.vote, window=3))
    load = lambda i: scenes.frame(i, density=2)  # noqa: E731
    plan = plan_refinement((load(i) for i in range(n_frames)), scenes.SETS, params)
    tracemalloc.start()
    for _ in refine_block(load, plan.frames, plan, scenes.SETS, params):
        pass
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return peak


def test_peak_memory_is_flat_in_the_sequence_length():
    short, long = _peak_bytes(15), _peak_bytes(60)
    assert long < 1.25 * short, (short, long)


def test_near_returns_outvote_far_ones():
    # one world voxel: two returns from 5 m say road, three from 105 m say sidewalk
    pose = np.eye(4)
    pose[0, 3] = -100.0
    near = FrameInput(0, 0.0, np.eye(4), np.array([[5, 0, 0], [5, 0.01, 0]], np.float32),
                      np.full(2, scenes.ROAD), np.zeros(2, np.int64))  # fmt: skip
    far = FrameInput(1, 0.1, pose, np.array([[105, 0, 0], [105, 0.01, 0], [105, 0.02, 0]], np.float32),
                     np.full(3, scenes.SIDEWALK), np.zeros(3, np.int64))  # fmt: skip
    grid = VoxelGrid(1.0)
    target = np.unique(np.concatenate([grid.keys(near.world()), grid.keys(far.world())]))
    assert target.size == 1
    none = Confidence.from_mapping(None)
    for range_ref, winner, votes in ((20.0, scenes.ROAD, 2 + 3 * 49 / 255), (None, scenes.SIDEWALK, 5.0)):
        fv = [
            frame_votes(f.index, grid.keys(f.world()), f.sem, None,
                        range_weights(f, range_ref) * none.point_weights(f.inst), 20, 3)
            for f in (near, far)
        ]  # fmt: skip
        c = window_consensus(target, fv, 20)
        # 105 m weighs round(255 * 20 / 105) = 49 / 255
        assert c.cls.tolist() == [winner] and c.frames.tolist() == [2]
        assert c.votes[0] == pytest.approx(votes)
