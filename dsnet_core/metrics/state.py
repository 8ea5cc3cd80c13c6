"""Save and restore a scorer's accumulator state as plain numpy arrays, and as ``.npz`` bytes.

The score stage scores blocks of frames in separate tasks; each block leaves its scorer's state
in the store, and sequence- and dataset-level numbers come from merging those states (never from
averaging per-frame numbers). The state is exact: ``result()`` of a restored and merged scorer
equals a one-pass scorer's bit for bit (float sums are kept as Shewchuk partials, counts as
integers). Every accumulator saves its own state (``state()`` / ``restore()``); a scorer's
state is its settings plus its metric set's (:class:`~.registry.MetricSet`, layout
:data:`~.registry.STATE_FORMAT`). A state of the layout before the metric registry is refused
with a ValueError saying to score again.
"""

from __future__ import annotations

import io

import numpy as np

from dsnet_core.labels import LabelMap

from .evaluator import PanopticEvaluator


def restore_evaluator(label_map: LabelMap, state: dict[str, np.ndarray]) -> PanopticEvaluator:
    """An evaluator of ``label_map`` holding ``state`` (settings from the state), ready to merge.

    Raises:
        ValueError: the state's layout, metrics or classes do not fit (the message says which).
    """
    if "format" not in state:
        PanopticEvaluator(label_map).metrics.check(state)  # raises: the layout before the registry
    ev = PanopticEvaluator(
        label_map,
        min_points=int(state["min_points"]),
        mode=str(state["mode"]),
        keep_rows=False,
        ignore=tuple(int(i) for i in state["ignore"]),
    )
    return ev.restore(state)


def state_to_bytes(state: dict[str, np.ndarray]) -> bytes:
    """``.npz`` bytes of a state (no pickling)."""
    buf = io.BytesIO()
    np.savez(buf, **state)
    return buf.getvalue()


def state_from_bytes(data: bytes) -> dict[str, np.ndarray]:
    """Inverse of :func:`state_to_bytes` (``allow_pickle=False``)."""
    with np.load(io.BytesIO(data), allow_pickle=False) as npz:
        return {k: npz[k] for k in npz.files}
