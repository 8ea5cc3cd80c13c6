import numpy as np
import pytest
import torch
import torch.nn.functional as F

from dsnet_core.model.losses import (
    class_weights,
    instance_centres,
    lovasz_softmax,
    offset_loss,
    semantic_loss,
)


def test_class_weights_inverse_sqrt_frequency():
    w = class_weights(np.array([1000, 100, 400, 0]))
    # freq 0.2 and 0.8 -> 1/sqrt: 2.236, 1.118 -> mean-normalised
    a, b = 0.2**-0.5, 0.8**-0.5
    assert w.tolist() == pytest.approx([0.0, 2 * a / (a + b), 2 * b / (a + b), 0.0])


def test_lovasz_is_zero_for_perfect_and_jaccard_for_hard_predictions():
    labels = torch.tensor([0, 1, 1, 2, 2, 2])
    onehot = F.one_hot(labels, 3).double()
    assert lovasz_softmax(onehot, labels).item() == pytest.approx(0.0)
    # hard predictions: the loss equals 1 - IoU averaged over present classes (ignoring class 0)
    pred = torch.tensor([1, 1, 2, 2, 2, 2])
    loss = lovasz_softmax(F.one_hot(pred, 3).double(), labels).item()
    # ignoring point 0: class 1 IoU = 1/2, class 2 IoU = 3/4
    assert loss == pytest.approx(1 - (0.5 + 0.75) / 2)


def test_semantic_loss_ignores_class_zero():
    logits = torch.randn(5, 4, requires_grad=True)
    labels = torch.tensor([0, 0, 0, 0, 0])
    assert semantic_loss(logits, labels).item() == 0.0
    labels = torch.tensor([0, 1, 2, 3, 1])
    loss = semantic_loss(logits, labels)
    loss.backward()
    assert logits.grad[0].abs().sum() == 0 and logits.grad[1:].abs().sum() > 0


def test_centres_are_tight_box_centres_not_centroids():
    xyz = torch.tensor([[0.0, 0, 0], [1, 0, 0], [10, 2, 0], [5, 5, 5], [7, 9, 1]])
    keys = torch.tensor([1, 1, 1, 2, 0])
    valid = torch.tensor([True, True, True, True, False])
    c = instance_centres(xyz, keys, valid)
    assert c.tolist() == [[5, 1, 0], [5, 1, 0], [5, 1, 0], [5, 5, 5], [0, 0, 0]]


def test_volume_centres_span_all_scans():
    # the same instance in two scans of a volume: the centre covers both
    xyz = torch.tensor([[0.0, 0, 0], [2, 0, 0], [4, 0, 0], [6, 0, 0]])
    keys = torch.tensor([7, 7, 7, 7])
    c = instance_centres(xyz, keys, torch.ones(4, dtype=torch.bool))
    assert c[:, 0].tolist() == [3, 3, 3, 3]


def test_offset_loss_eq1():
    xyz = torch.tensor([[0.0, 0, 0], [2, 0, 0], [9, 9, 9]])
    centres = torch.tensor([[1.0, 0, 0], [1, 0, 0], [0, 0, 0]])
    valid = torch.tensor([True, True, False])
    perfect = centres - xyz
    assert offset_loss(perfect, xyz, centres, valid).item() == 0.0
    off = perfect + torch.tensor([[0.5, -0.5, 0], [0, 0, 1], [100, 100, 100]])
    assert offset_loss(off, xyz, centres, valid).item() == pytest.approx((1.0 + 1.0) / 2)
    assert offset_loss(off, xyz, centres, torch.zeros(3, dtype=torch.bool)).item() == 0.0


def test_voxel_labels_majority_ignoring_unlabelled():
    from dsnet_core.model.losses import voxel_labels

    p2v = torch.tensor([0, 0, 0, 1, 1, 2, 2, 2])
    lab = torch.tensor([3, 3, 1, 0, 2, 0, 0, 0])
    assert voxel_labels(p2v, lab, 4, 5).tolist() == [3, 2, 0, 0]
