"""Track decisions: one class per track, joins across gaps in both directions, moving vs static,
dissolving, and the plan's JSON round trip."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from dsnet_core.refine import (
    RefineParams,
    RefinePlan,
    TrackParams,
    plan_refinement,
    refine_sequence,
    track_rows,
)
from dsnet_core.refine.frame import FrameInput
from dsnet_core.refine.history import TrackHistory, frame_tracks
from dsnet_core.refine.joining import chain_heads, join_tracks
from tests.dsnet_core.refine import scenes


def _keep(f: FrameInput, keep: np.ndarray) -> FrameInput:
    probs = None if f.probs is None else f.probs[keep]
    return replace(f, xyz=f.xyz[keep], sem=f.sem[keep], inst=f.inst[keep], probs=probs)


def _relabel(f: FrameInput, old: int, new: int) -> FrameInput:
    return replace(f, inst=np.where(f.inst == old, new, f.inst))


@pytest.fixture(scope="module")
def street():
    return scenes.sequence(30)


@pytest.mark.parametrize("soft", [False, True])
def test_a_track_flipped_on_30_percent_of_its_frames_gets_one_class(street, soft):
    rng = np.random.default_rng(5)
    flipped = set(rng.choice(30, 9, replace=False).tolist())
    frames = []
    for f in street:
        sem = f.sem.copy()
        if f.index in flipped:
            sem[f.inst == 2] = scenes.TRUCK  # the overtaking car: 9 of its 30 frames
            sem[f.inst == 1] = scenes.PERSON  # the parked car (another group): 6 of its 17 frames
        g = replace(f, sem=sem)
        frames.append(scenes.soft_probs(g) if soft else g)
    # the overtaking car's vote beats truck 2.2 (2.3 one-hot) to 1: every point takes car. The
    # parked car's beats person 2.07 to 1 one-hot, 1.9999 to 1 soft: below the default
    # class_margin of 2, its confidently-person frames (0.7 to 0.02) keep person there
    plurality = RefineParams(track=TrackParams(class_margin=0.0))
    for params, parked in ((RefineParams(), {scenes.CAR} if not soft else {scenes.CAR, scenes.PERSON}),
                           (plurality, {scenes.CAR})):  # fmt: skip
        out = refine_sequence(frames, scenes.SETS, params)
        for o, f in zip(out, street, strict=True):
            assert set(o.sem[o.inst == 2].tolist()) <= {scenes.CAR}
            assert set(o.sem[o.inst == 1].tolist()) <= parked
            if parked == {scenes.CAR, scenes.PERSON} and f.index in flipped and (f.inst == 1).any():
                assert (o.sem[o.inst == 1] == scenes.PERSON).all()
            np.testing.assert_array_equal(o.inst, f.inst)
        changed = {o.index for o in out if o.change.by_track}
        assert changed == {f for f in flipped if (street[f].inst > 0).any()}


def _two_class_track(sightings, a: int, b: int, n_classes: int = 20) -> list[FrameInput]:
    """One track (id 5) seen once per frame: ``sightings`` is a list of ``(points, p_a, p_b,
    own)``: that many points with probability ``p_a`` of class ``a`` and ``p_b`` of ``b`` (the rest
    on road), labelled ``own``. The points sit still 10 m ahead (range weight 1)."""
    frames = []
    for t, (n, pa, pb, own) in enumerate(sightings):
        probs = np.zeros((n, n_classes))
        probs[:, a], probs[:, b], probs[:, scenes.ROAD] = pa, pb, 1 - pa - pb
        xyz = np.tile(np.array([[10.0, 0.0, 0.5]], np.float32), (n, 1)) + np.arange(n)[:, None] * 1e-3
        sem, inst = np.full(n, own, np.int64), np.full(n, 5, np.int64)
        frames.append(
            FrameInput(t, 0.1 * t, np.eye(4), xyz, sem, inst, np.rint(probs * 255).astype(np.uint8))
        )
    return frames


def test_a_confident_motorcycle_is_not_voted_into_a_motorcyclist_by_a_close_vote():
    moto, rider = 3, 8  # one association group: the tracker may mix them in one track
    # six far frames of a clear motorcycle (0.6 vs 0.3) and two near frames with many points
    # that lean motorcyclist (0.55 vs 0.35): the points' summed vote says motorcyclist, 292 to 284
    frames = _two_class_track([(40, 0.6, 0.3, moto)] * 6 + [(200, 0.35, 0.55, rider)] * 2, moto, rider)
    d = plan_refinement(frames, scenes.SETS, RefineParams()).decisions
    assert d.class_id.tolist() == [rider]
    out = refine_sequence(frames, scenes.SETS, RefineParams())
    assert [set(o.sem.tolist()) for o in out] == [{moto}] * 6 + [{rider}] * 2  # each keeps its own
    assert all(o.change.by_track == 0 for o in out)
    rows = track_rows(d)
    assert rows[0]["class_id"] == rider and rows[0]["kept_classes"] == [moto]
    # the bare plurality (class_margin 0, refine before version 3) made all of it motorcyclist
    plurality = refine_sequence(frames, scenes.SETS, RefineParams(track=TrackParams(class_margin=0.0)))
    assert all(set(o.sem.tolist()) == {rider} for o in plurality)


def test_an_unsure_instance_takes_its_tracks_class_and_a_clear_vote_overrules_a_sure_one():
    car, truck = scenes.CAR, scenes.TRUCK
    # a close vote (car 200 to truck 160): the two unsure truck frames (0.5 vs 0.4) take car
    frames = _two_class_track([(40, 0.6, 0.3, car)] * 5 + [(100, 0.4, 0.5, truck)] * 2, car, truck)
    out = refine_sequence(frames, scenes.SETS, RefineParams())
    assert all(set(o.sem.tolist()) == {car} for o in out)
    assert [o.change.by_track for o in out] == [0] * 5 + [100, 100]
    # a clear vote (9 frames of car 0.7 against one sure truck frame 0.7 vs 0.2) overrules it
    frames = _two_class_track([(40, 0.7, 0.2, car)] * 9 + [(40, 0.2, 0.7, truck)], car, truck)
    out = refine_sequence(frames, scenes.SETS, RefineParams())
    assert all(set(o.sem.tolist()) == {car} for o in out) and out[-1].change.by_track == 40
    assert plan_refinement(frames, scenes.SETS, RefineParams()).decisions.kept_key.size == 0


def test_class_margin_default_and_refusal():
    from pydantic import ValidationError

    from tasks.methods import stage_config_line
    from tasks.refine import RefineConfig, refine_params

    assert RefineConfig().class_margin == 2.0 == TrackParams().class_margin
    assert refine_params(RefineConfig(class_margin=3.5)).track.class_margin == 3.5
    with pytest.raises(ValidationError) as exc:
        RefineConfig(class_margin=-1)
    line = stage_config_line("refine", exc.value)
    assert "\n" not in line and "class_margin" in line
    with pytest.raises(ValueError, match="class_margin must be at least 0, got -1"):
        TrackParams(class_margin=-1)


def test_a_track_cut_by_a_three_frame_gap_is_joined_with_its_earliest_id(street):
    frames = []
    for f in street:
        if 10 <= f.index <= 12:  # the overtaking car is missed for three frames...
            f = _keep(f, f.inst != 2)
        elif f.index > 12:  # ... and comes back as a new track
            f = _relabel(f, 2, 7)
        frames.append(f)
    plan = plan_refinement(frames, scenes.SETS, RefineParams())
    (join,) = plan.decisions.joins
    assert (join.earlier, join.later, join.gap) == (2, 7, 3) and join.distance < 0.5
    out = refine_sequence(frames, scenes.SETS, RefineParams())
    for o, f in zip(out, frames, strict=True):
        assert 7 not in o.inst
        np.testing.assert_array_equal(o.inst == 2, (f.inst == 2) | (f.inst == 7))
    assert [o.change.tracks_joined for o in out].count(1) == 1 and out[13].change.tracks_joined == 1
    assert out[13].change.id_changed == int((frames[13].inst == 7).sum())


def test_the_earliest_track_keeps_its_id_even_when_the_later_one_has_a_smaller_number(street):
    frames = []
    for f in street:
        if f.index < 10:
            f = _relabel(f, 2, 9)
        elif f.index <= 11:
            f = _keep(f, f.inst != 2)
        frames.append(f)  # frames >= 12 keep id 2
    out = refine_sequence(frames, scenes.SETS, RefineParams())
    assert all(2 not in o.inst for o in out)
    assert all(
        np.array_equal(o.inst == 9, (f.inst == 9) | (f.inst == 2)) for o, f in zip(out, frames, strict=True)
    )


def test_no_join_beyond_the_gap_or_across_class_groups(street):
    frames = []
    for f in street:
        if 10 <= f.index <= 16:  # seven frames unseen: G = 5 does not bridge it
            f = _keep(f, f.inst != 2)
        elif f.index > 16:
            f = _relabel(f, 2, 7)
        frames.append(f)
    assert plan_refinement(frames, scenes.SETS, RefineParams()).decisions.joins == ()
    wide = RefineParams(track=TrackParams(join_gap=7, join_distance=3.0))
    assert len(plan_refinement(frames, scenes.SETS, wide).decisions.joins) == 1
    person = [replace(f, sem=np.where(f.inst == 7, scenes.PERSON, f.sem)) for f in frames]
    assert plan_refinement(person, scenes.SETS, wide).decisions.joins == ()


def test_joins_are_one_to_one():
    # two tracks end at frame 4 side by side, one starts at frame 6 between their extrapolations
    hist = TrackHistory(20)
    for t in range(10):
        pts, ids = [], []
        for tid, y in ((1, 0.0), (2, 1.0)) if t <= 4 else ((3, 0.4),) if t >= 6 else ():
            pts.append(np.array([[t * 1.0, y, 0.0]] * 4, np.float32) + np.arange(4)[:, None] * 0.01)
            ids.append(np.full(4, tid))
        xyz = np.concatenate(pts) if pts else np.zeros((0, 3), np.float32)
        inst = np.concatenate(ids) if ids else np.zeros(0, np.int64)
        f = FrameInput(t, 0.1 * t, np.eye(4), xyz, np.full(inst.size, scenes.CAR), inst)
        hist.add(frame_tracks(f, scenes.plan_confidence(), None, 20))
    s = hist.summary()
    joins = join_tracks(s, np.ones(3, bool), np.zeros(3, np.int64), max_gap=2, max_distance=2.0)
    assert [(j.earlier, j.later, j.gap) for j in joins] == [(1, 3, 1)]
    assert chain_heads(s.ids, joins).tolist() == [1, 2, 1]


def test_a_moving_car_passing_a_parked_one_keeps_its_class_and_id(street):
    noisy, _ = scenes.add_static_noise(street, 0.2)
    noisy = [replace(n, sem=np.where(n.inst > 0, g.sem, n.sem)) for n, g in zip(noisy, street, strict=True)]
    plan = plan_refinement(noisy, scenes.SETS, RefineParams())
    d = plan.decisions
    assert d.ids.tolist() == [1, 2, 3]
    assert d.static.tolist() == [True, False, False]  # the parked car stays put; car and person move
    assert d.class_id.tolist() == [scenes.CAR, scenes.CAR, scenes.PERSON]
    out = refine_sequence(noisy, scenes.SETS, RefineParams())
    for o, g in zip(out, street, strict=True):
        things = g.inst > 0
        np.testing.assert_array_equal(o.inst, g.inst)  # neither absorbed nor re-identified
        np.testing.assert_array_equal(o.sem[things], g.sem[things])
    # the static vote only ever changed stuff points
    assert all(
        not (o.change.by_static and (o.sem != n.sem)[n.inst > 0].any())
        for o, n in zip(out, noisy, strict=True)
    )


def test_a_short_stuff_like_track_dissolves_into_the_static_vote(street):
    frames = []
    for f in street:
        if f.index in (8, 9):  # a piece of the hedge detected as an object for two frames
            bush = (f.sem == scenes.VEGETATION) & (f.world()[:, 0] < 10)
            f = replace(f, inst=np.where(bush, 11, f.inst))
        frames.append(f)
    plan = plan_refinement(frames, scenes.SETS, RefineParams())
    row = plan.decisions.lookup(np.array([11]))[0]
    assert plan.decisions.dissolved[row] and plan.decisions.final_id[row] == 0
    assert plan.decisions.class_id[row] == scenes.VEGETATION
    out = refine_sequence(frames, scenes.SETS, RefineParams())
    assert (
        11 not in out[8].inst and out[8].change.tracks_dissolved == 1 and out[7].change.tracks_dissolved == 0
    )
    np.testing.assert_array_equal(out[8].sem, street[8].sem)


def test_the_plan_round_trips_through_json(street):
    frames = [_relabel(f, 2, 7) if f.index > 12 else f for f in street if not 10 <= f.index <= 12]
    plan = plan_refinement(frames, scenes.SETS, RefineParams(), confidence={1: 0.9, 2: 0.4})
    back = RefinePlan.from_dict(json.loads(json.dumps(plan.to_dict())))
    assert back.to_dict() == plan.to_dict()
    assert back.frames == tuple(f.index for f in frames)
    assert back.confidence.weight.tolist() == [230, 102]


def test_without_poses_only_the_track_classes_apply_and_without_tracks_only_the_vote(street):
    noisy, _ = scenes.add_static_noise(street[:8], 0.2)
    flipped = [
        replace(f, sem=np.where(f.inst == 1, scenes.TRUCK, f.sem)) if f.index % 3 == 0 else f for f in noisy
    ]
    posed = [replace(f, pose=None) for f in flipped]
    plan = plan_refinement(posed, scenes.SETS, RefineParams())
    assert not plan.world and not plan.decisions.static.any() and plan.decisions.joins == ()
    out = refine_sequence(posed, scenes.SETS, RefineParams())
    assert all(o.change.by_static == 0 and o.change.by_track == int((f.inst == 1).sum()) * (f.index % 3 == 0)
               for o, f in zip(out, posed, strict=True))  # fmt: skip
    assert refine_sequence([], scenes.SETS, RefineParams()) == []
    no_tracks = [replace(f, inst=np.zeros_like(f.inst)) for f in noisy]
    out = refine_sequence(no_tracks, scenes.SETS, RefineParams())
    assert all(o.change.by_track == 0 for o in out) and sum(o.change.by_static for o in out) > 0


@pytest.mark.parametrize("reused", [True, False])
def test_a_join_is_refused_where_it_would_stretch_a_reused_id_over_another_track(street, reused):
    # the overtaking car (2) is missed in frames 10-12 and comes back as 7; the person appears at
    # frame 20 under id 2 again (a temporal stage that ran out of ids: key 2 | 1 << 16) or, as a
    # control, under a reused id of another number (9 | 1 << 16)
    other = (2 if reused else 9) | 1 << 16
    frames = []
    for f in street:
        if 10 <= f.index <= 12:
            f = _keep(f, f.inst != 2)
        elif f.index > 12:
            f = _relabel(f, 2, 7)
        f = _keep(f, f.inst != 3) if f.index < 20 else _relabel(f, 3, other)
        frames.append(f)
    d = plan_refinement(frames, scenes.SETS, RefineParams()).decisions
    assert d.refused == int(reused) and len(d.joins) == 1 - int(reused)
    out = refine_sequence(frames, scenes.SETS, RefineParams())
    for o, f in zip(out, frames, strict=True):
        car = o.inst[(f.inst == 2) | (f.inst == 7)]
        assert set(car.tolist()) <= ({2} if f.index < 10 else {7} if reused else {2})
        np.testing.assert_array_equal(o.inst[f.inst == other], other)  # the person keeps its track
    rows = track_rows(d)
    expected = [(1, 0), (2, 0), (2, 1), (7, 0)] if reused else [(1, 0), (2, 0), (9, 1)]
    assert [(r["id"], r["generation"]) for r in rows] == expected  # sorted by (id, generation)
    plan = plan_refinement(frames, scenes.SETS, RefineParams())
    assert RefinePlan.from_dict(json.loads(json.dumps(plan.to_dict()))).decisions.refused == int(reused)
