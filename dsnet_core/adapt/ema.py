"""The mean teacher: an exponential moving average of the student's weights (Tarvainen & Valpola,
NeurIPS 2017). After every student step ``θ_t ← d · θ_t + (1 − d) · θ_s`` for every floating-point
parameter and buffer (batch-norm statistics included); integer buffers (batch-norm's step count)
are copied. The teacher smooths the student over its last ``1 / (1 − d)`` steps or so: it labels
the next round and is the checkpoint adaptation writes.
"""

from __future__ import annotations

import torch

from dsnet_core.errors import ConfigError


@torch.no_grad()
def ema_update(teacher: torch.nn.Module, student: torch.nn.Module, decay: float) -> None:
    """One EMA step of ``teacher`` towards ``student`` (same architecture), in place.

    Raises:
        ConfigError: ``decay`` outside [0, 1], or the two models' tensors differ in names or shapes.
    """
    if not 0.0 <= decay <= 1.0:
        raise ConfigError(f"EMA decay must be in [0, 1], got {decay}")
    t_state, s_state = teacher.state_dict(), student.state_dict()
    if t_state.keys() != s_state.keys():
        raise ConfigError("EMA teacher and student have different tensors")
    for name, t in t_state.items():
        s = s_state[name]
        if t.shape != s.shape:
            raise ConfigError(
                f"EMA: {name} is {tuple(t.shape)} in the teacher, {tuple(s.shape)} in the student"
            )
        if t.dtype.is_floating_point:
            t.mul_(decay).add_(s.detach().to(t.dtype), alpha=1.0 - decay)
        else:
            t.copy_(s)
