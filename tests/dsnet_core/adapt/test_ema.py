"""The mean teacher's arithmetic: θ_t ← d·θ_t + (1 − d)·θ_s for parameters and float buffers,
integer buffers copied."""

import pytest
import torch

from dsnet_core.adapt import ema_update
from dsnet_core.errors import ConfigError


def net(value: float) -> torch.nn.Module:
    m = torch.nn.Sequential(torch.nn.Linear(2, 2), torch.nn.BatchNorm1d(2))
    with torch.no_grad():
        for t in m.state_dict().values():
            if t.dtype.is_floating_point:
                t.fill_(value)
    return m


def test_ema_steps_towards_the_student():
    teacher, student = net(0.0), net(1.0)
    student[1].num_batches_tracked.fill_(5)
    ema_update(teacher, student, 0.9)
    assert torch.allclose(teacher[0].weight, torch.full((2, 2), 0.1))
    assert torch.allclose(teacher[1].running_var, torch.full((2,), 0.1))  # buffers too
    assert int(teacher[1].num_batches_tracked) == 5  # integer buffers are copied
    ema_update(teacher, student, 0.9)
    assert torch.allclose(teacher[0].bias, torch.full((2,), 0.19))  # 0.9·0.1 + 0.1
    for _ in range(200):
        ema_update(teacher, student, 0.9)
    assert torch.allclose(teacher[0].weight, torch.ones(2, 2), atol=1e-6)
    assert torch.equal(student[0].weight, torch.ones(2, 2))  # the student is untouched


def test_decay_zero_copies_and_one_freezes():
    teacher, student = net(0.25), net(2.0)
    ema_update(teacher, student, 1.0)
    assert torch.equal(teacher[0].weight, torch.full((2, 2), 0.25))
    ema_update(teacher, student, 0.0)
    assert torch.equal(teacher[0].weight, student[0].weight)


def test_mismatched_models_and_bad_decay_are_refused():
    with pytest.raises(ConfigError, match="decay must be in"):
        ema_update(net(0), net(1), 1.5)
    with pytest.raises(ConfigError, match="different tensors"):
        ema_update(net(0), torch.nn.Linear(2, 2), 0.5)
