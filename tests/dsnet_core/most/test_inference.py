"""MOST inference: heatmap NMS and decoding, RoIs, memberships and overlap resolution."""

import numpy as np
import torch

from dsnet_core.most.config import BevGrid
from dsnet_core.most.heatmap import bev_targets
from dsnet_core.most.inference import (
    Detections,
    assign_instances,
    decode_heatmap,
    distance_membership,
    roi_pairs,
)
from dsnet_core.most.predict import InferenceSettings, panoptic
from dsnet_core.most.targets import ObjectTargets

THINGS = (1, 2, 3, 4, 5, 6, 7, 8)
CAR, PERSON, ROAD = 1, 6, 9
GRID = BevGrid(half_extent=20.0, cell=0.5)


def targets():
    return ObjectTargets(
        np.array([(CAR << 32) | 1, (CAR << 32) | 2, (PERSON << 32) | 3]),
        np.array([CAR, CAR, PERSON]),
        np.array([[5.3, -2.1, -0.8], [5.6, 2.4, -1.0], [-3.05, 3.2, -0.9]]),
        np.array([[2.0, 0.9, 0.7], [2.1, 1.0, 0.7], [0.3, 0.3, 0.9]]),
        np.array([[1.0, 0.5], [-2.0, 0.0], [0.2, 0.1]]),
        np.array([True, True, True]),
    )


def maps_of(tg, s):
    """Logits and regression maps that reproduce the targets exactly."""
    heat = torch.logit(torch.from_numpy(tg.heatmap).double().clamp(1e-9, 1 - 1e-9))
    reg = torch.zeros(8, s * s, dtype=torch.float64)
    idx = torch.from_numpy(tg.index)
    reg[0:2, idx] = torch.from_numpy(tg.offset).double().t()
    reg[2, idx] = torch.from_numpy(tg.height).double()
    reg[3:6, idx] = torch.from_numpy(tg.extent).double().t()
    reg[6:8, idx] = torch.from_numpy(tg.velocity).double().t()
    return heat, reg.view(8, s, s)


def test_decoding_perfect_maps_recovers_the_objects():
    t = targets()
    heat, reg = maps_of(bev_targets(t, GRID, THINGS), GRID.size)
    det = decode_heatmap(heat, reg, GRID, THINGS)
    assert len(det) == 3 and np.allclose(det.scores, 1.0)
    order = np.argsort(det.centres[:, 0])
    np.testing.assert_allclose(det.centres[order], t.centres[[2, 0, 1]], atol=1e-5)
    np.testing.assert_allclose(det.extents[order], t.extents[[2, 0, 1]], atol=1e-5)
    np.testing.assert_allclose(det.velocity[order], t.velocity[[2, 0, 1]], atol=1e-5)
    assert det.classes[order].tolist() == [PERSON, CAR, CAR]
    # a confidence threshold above the peaks leaves nothing; the Gaussian flanks are suppressed
    assert len(decode_heatmap(heat, reg, GRID, THINGS, threshold=1.01)) == 0
    assert len(decode_heatmap(heat, reg, GRID, THINGS, threshold=0.01)) == 3


def scene(rng):
    """Two touching cars, a person, road: points, gt semantic, gt instance."""
    parts = [
        (np.array([5.0, -1.0, -0.8]), [1.9, 0.85, 0.6], CAR, 1, 300),
        (np.array([5.0, 0.9, -0.8]), [1.9, 0.85, 0.6], CAR, 2, 300),
        (np.array([-3.0, 3.0, -0.9]), [0.25, 0.25, 0.8], PERSON, 3, 80),
    ]
    xyz, sem, inst = (
        [rng.uniform(-15, 15, (500, 3)) * [1, 1, 0] + [0, 0, -1.7]],
        [np.full(500, ROAD)],
        [np.zeros(500)],
    )
    for c, h, cls, i, n in parts:
        xyz.append(c + rng.uniform(-1, 1, (n, 3)) * h)
        sem.append(np.full(n, cls))
        inst.append(np.full(n, i))
    return np.concatenate(xyz), np.concatenate(sem).astype(np.int64), np.concatenate(inst).astype(np.int64)


def dets(centres, classes, scores, extents):
    n = len(classes)
    return Detections(
        np.asarray(centres, float),
        np.asarray(classes),
        np.asarray(scores, float),
        np.asarray(extents, float),
        np.zeros((n, 2)),
    )


def test_distance_rule_splits_touching_cars_and_keeps_stuff():
    xyz, sem, inst = scene(np.random.default_rng(0))
    det = dets(
        [[5.0, -1.0, -0.8], [5.0, 0.9, -0.8], [-3.0, 3.0, -0.9]],
        [CAR, CAR, PERSON],
        [0.9, 0.8, 0.7],
        [[2, 1, 0.7], [2, 1, 0.7], [0.3, 0.3, 0.9]],
    )
    pred = panoptic(xyz, sem, det, InferenceSettings(rule="distance"))
    np.testing.assert_array_equal(pred.semantic, sem)  # semantics untouched
    assert (pred.instance[sem == ROAD] == 0).all()
    for gt, want in ((1, 1), (2, 2), (3, 3)):  # ids 1.. by decreasing confidence
        assert np.unique(pred.instance[inst == gt]).tolist() == [want]
    np.testing.assert_array_equal(pred.detections.classes, [CAR, CAR, PERSON])


def test_rois_need_the_detection_class_and_its_box():
    xyz = np.array([[0.0, 0.0, 0.0], [1.9, 0.0, 0.0], [2.5, 0.0, 0.0], [0.5, 0.0, 0.0]])
    sem = np.array([CAR, CAR, CAR, PERSON])
    det = dets([[0.0, 0.0, 0.0]], [CAR], [1.0], [[1.5, 1.0, 1.0]])
    d, p = roi_pairs(xyz, sem, det, scale=1.1, margin=0.2)  # half-size 1.85 m in x
    assert d.tolist() == [0] and p.tolist() == [0]
    d, p = roi_pairs(xyz, sem, det, scale=1.2, margin=0.2)  # 2.0 m
    assert p.tolist() == [0, 1]


def test_overlaps_go_to_the_highest_membership_then_the_more_confident_centre():
    # detections 0 (more confident) and 1 share points 1 and 2
    pairs = (np.array([0, 0, 0, 1, 1, 1]), np.array([0, 1, 2, 1, 2, 3]))
    scores = {(0, 0): 0.9, (0, 1): 0.6, (0, 2): 0.7, (1, 1): 0.8, (1, 2): 0.7, (1, 3): 0.4}

    def member(d, p):
        return np.array([scores[(int(a), int(b))] for a, b in zip(d, p, strict=True)])

    inst, used = assign_instances(5, pairs, member, threshold=0.5)
    assert inst.tolist() == [1, 2, 1, 0, 0]  # point 2 ties → detection 0; point 3 below 0.5
    assert used.tolist() == [0, 1]
    # a detection that keeps no point gets no id; ids stay consecutive
    inst, used = assign_instances(
        5, (np.array([0, 1, 2]), np.array([0, 1, 2])), lambda d, p: np.array([0.9, 0.1, 0.8])
    )
    assert inst.tolist() == [1, 0, 2, 0, 0] and used.tolist() == [0, 2]


def test_distance_membership_prefers_the_nearer_centre():
    xyz = np.array([[0.0, 0.0, 0.0], [3.0, 0.0, 0.0]])
    det = dets([[0.5, 0, 0], [2.0, 0, 0]], [CAR, CAR], [1.0, 0.5], [[3, 3, 3], [3, 3, 3]])
    inst, _ = assign_instances(
        2, roi_pairs(xyz, np.array([CAR, CAR]), det), distance_membership(xyz, det), 0.0
    )
    assert inst.tolist() == [1, 2]


def test_predict_wires_network_detections_and_pointsegmlp():
    from dsnet_core.most.network import MostNet
    from dsnet_core.most.predict import predict
    from tests.dsnet_core.most.test_network import CFG

    torch.manual_seed(0)
    net = MostNet(CFG)
    with torch.no_grad():
        net.bev_head.heatmap.bias.fill_(3.0)  # every cell confident: NMS keeps the local maxima
    xyz, _, _ = scene(np.random.default_rng(1))
    cloud = np.concatenate(
        [np.c_[xyz, np.zeros((len(xyz), 2))], np.c_[xyz[:100], np.zeros(100), np.full(100, 0.1)]]
    )
    cloud = torch.from_numpy(cloud.astype(np.float32))
    for rule in ("mlp", "distance"):
        pred = predict(net, cloud, len(xyz), InferenceSettings(rule=rule, max_detections=20))
        assert pred.semantic.shape == pred.instance.shape == (len(xyz),)
        n = int(pred.instance.max())
        assert len(pred.detections) == n and np.unique(pred.instance[pred.instance > 0]).tolist() == list(
            range(1, n + 1)
        )
        for i in range(1, n + 1):  # members carry their detection's class
            assert (pred.semantic[pred.instance == i] == pred.detections.classes[i - 1]).all()
