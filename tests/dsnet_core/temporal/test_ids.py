"""The 16-bit id pool: a plain counter until it runs out, then least-recently-used ids unused for
more than the reuse window; its state round-trips; generations map a frame's ids back to tracks."""

import json

import numpy as np
import pytest

from dsnet_core.temporal.ids import (
    MAX_ID,
    Generations,
    IdPool,
    IdSpaceExhausted,
    key_generation,
    key_id,
    track_key,
)


def test_the_counter_hands_out_1_to_65535_in_order_before_any_reuse():
    pool = IdPool(reuse_after=3)
    got = [pool.take(0) for _ in range(MAX_ID)]
    assert got == list(range(1, MAX_ID + 1)) and pool.reused == 0 and pool.next_id == MAX_ID + 1


def test_exhausted_ids_come_back_least_recently_used_first_after_the_window():
    pool = IdPool(reuse_after=3)
    for tid in range(1, MAX_ID + 1):
        pool.take(4 * (tid - 1) // MAX_ID)  # ids 1..16384 at frame 0, then frames 1, 2, 3
    pool.touch([1], 4)  # id 1 is still in use at frame 4: no longer the least recently used
    with pytest.raises(IdSpaceExhausted, match=r"no instance id free at frame 4: all 65535 ids .* last 4"):
        IdPool.from_state({**pool.state_dict(), "reuse_after": 4}).take(4)  # frame 0 is 4 frames back
    key = pool.take(4)
    assert key_id(key) == 2 and key_generation(key) == 1 and key == track_key(2, 1) == 2 | 1 << 16
    assert [key_id(pool.take(4)) for _ in range(2)] == [3, 4] and pool.reused == 3
    assert pool.key(2) == key and pool.key(9) == 9
    with pytest.raises(ValueError, match="must not decrease"):
        pool.touch([1], 3)
    with pytest.raises(ValueError, match="at least 1 frame"):
        IdPool(reuse_after=0)


def test_a_touched_id_is_never_handed_out_inside_the_window():
    pool = IdPool(reuse_after=5)
    for _ in range(MAX_ID):
        pool.take(0)
    live = [7, 70, 700]
    handed: dict[int, int] = {}
    for frame in range(6, 40):
        pool.touch(live, frame)  # a carried / coasting track, every frame
        for _ in range(2000):
            tid = key_id(pool.take(frame))
            assert tid not in live and frame - handed.get(tid, -99) > 5
            handed[tid] = frame
            pool.touch([tid], frame)


def test_state_round_trips_through_json_and_continues_identically():
    a = IdPool(reuse_after=2)
    for f in range(MAX_ID // 1000 + 3):
        for _ in range(1000):
            a.take(f)
    b = IdPool.from_state(json.loads(json.dumps(a.state_dict())))
    assert b.reused == a.reused > 0 and b.next_id == a.next_id
    for f in range(70, 80):
        assert [a.take(f) for _ in range(700)] == [b.take(f) for _ in range(700)]
    assert len(json.dumps(a.state_dict())) < 300_000


def test_generations_map_ids_of_a_frame_to_their_tracks():
    # id 5: generation 0 in frames 0-9, generation 1 from frame 200; id 6 never reused
    g = Generations(np.array([5, 6, 5]), np.array([0, 0, 1]), np.array([0, 3, 200]))
    assert g.reused
    inst = np.array([0, 5, 6, 5])
    assert g.keys(inst, 9).tolist() == [0, 5, 6, 5]
    assert g.keys(inst, 200).tolist() == [0, 5 | 1 << 16, 6, 5 | 1 << 16]
    assert g.keys(np.array([7]), 500).tolist() == [7]  # an id without rows: generation 0
    plain = Generations(np.array([5, 6]), np.array([0, 0]), np.array([0, 3]))
    assert not plain.reused and plain.keys(inst, 9).tolist() == [0, 5, 6, 5]
    assert Generations.none().keys(inst, 0).tolist() == inst.tolist()
