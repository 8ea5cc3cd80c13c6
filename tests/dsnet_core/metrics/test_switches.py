import numpy as np

from dsnet_core.labels import load_label_map
from dsnet_core.metrics.switches import SwitchCounter

LM = load_label_map("semantic-kitti")
CAR, PERSON, ROAD = 10, 30, 40  # raw ids


def count_switches(gts, preds, label_map, min_points):
    """A SwitchCounter fed one sequence's frames, as the scorer feeds it."""
    counter = SwitchCounter(label_map, min_points=min_points)
    for gt, pred in zip(gts, preds, strict=True):
        counter.add(gt, pred, "")
    return counter


def lab(sem, inst):
    return (np.asarray(sem, np.uint32) | (np.asarray(inst, np.uint32) << 16)).astype(np.uint32)


# 10 points: 4 of car 1, 3 of person 2, 3 of road
GT = lab([CAR] * 4 + [PERSON] * 3 + [ROAD] * 3, [1] * 4 + [2] * 3 + [0] * 3)


def test_consistent_ids_never_switch():
    pred = lab([CAR] * 4 + [PERSON] * 3 + [ROAD] * 3, [7] * 4 + [9] * 3 + [0] * 3)
    c = count_switches([GT] * 5, [pred] * 5, LM, min_points=1)
    assert (c.switches, c.matches, c.tubes) == (0, 10, 2)


def test_fresh_ids_every_frame_switch_every_frame():
    preds = [
        lab([CAR] * 4 + [PERSON] * 3 + [ROAD] * 3, [2 * f + 1] * 4 + [2 * f + 2] * 3 + [0] * 3)
        for f in range(4)
    ]
    c = count_switches([GT] * 4, preds, LM, min_points=1)
    assert (c.switches, c.matches) == (6, 8)  # each tube: m - 1 = 3


def test_unmatched_frame_keeps_memory_and_iou_must_exceed_half():
    c = SwitchCounter(LM, min_points=1)
    good = lab([CAR] * 4 + [PERSON] * 3 + [ROAD] * 3, [5] * 4 + [0] * 6)
    half = lab([CAR] * 4 + [PERSON] * 3 + [ROAD] * 3, [5] * 2 + [6] * 2 + [0] * 6)  # IoU 0.5: no match
    assert [c.add(GT, good), c.add(GT, half), c.add(GT, good)] == [0, 0, 0]
    assert (c.switches, c.matches, c.tubes) == (0, 2, 1)
    moved = lab([CAR] * 4 + [PERSON] * 3 + [ROAD] * 3, [8] * 3 + [0] * 7)  # IoU 0.75 with another id
    assert c.add(GT, moved) == 1
    # the class of the prediction does not matter, only its id; sequences are independent
    assert c.add(GT, lab([PERSON] * 4 + [ROAD] * 6, [8] * 4 + [0] * 6)) == 0
    assert c.add(GT, good, sequence="other") == 0


def test_segments_below_min_points_are_not_counted():
    preds = [lab([CAR] * 4 + [PERSON] * 3 + [ROAD] * 3, [f + 1] * 4 + [0] * 6) for f in range(3)]
    assert count_switches([GT] * 3, preds, LM, min_points=5).matches == 0
    c = count_switches([GT] * 3, preds, LM, min_points=4)
    assert (c.switches, c.matches) == (2, 3)
