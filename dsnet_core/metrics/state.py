"""Save and restore a :class:`PanopticEvaluator`'s accumulator state as plain numpy arrays.

The score stage scores blocks of frames in separate tasks; each block leaves its accumulator
state in the store, and sequence- and dataset-level numbers come from merging those states
(never from averaging per-frame numbers). The state is exact: ``result()`` of a restored and
merged evaluator equals a one-pass evaluator's bit for bit (float sums are kept as Shewchuk
partials, counts as integers).

``evaluator_state(ev)`` gives ``{name: ndarray}`` (``np.savez`` ready); ``restore_evaluator``
rebuilds an evaluator from it. Per-frame rows are not part of the state.
"""

from __future__ import annotations

import io

import numpy as np

from dsnet_core.labels import LabelMap

from .cells import CountTable, ExactSum
from .evaluator import PanopticEvaluator
from .lstq import _SeqTables

_TABLES = ("preds", "tubes", "inter")


def evaluator_state(ev: PanopticEvaluator) -> dict[str, np.ndarray]:
    """The accumulator state of ``ev`` as named arrays (rows excluded).

    Keys: ``meta`` (int64 ``[min_points, frames_pq, frames_lstq]``), ``mode`` (str), ``ignore``,
    ``pq_conf`` ``(C, C)``, ``pq_tp/fp/fn`` ``(C,)``, ``pq_partials`` (float64, concatenated)
    with ``pq_partials_len`` ``(C,)``, ``lstq_conf`` ``(C, C)``, ``lstq_seqs`` (str ``(S,)``)
    and for sequence ``i`` ``lstq_{i}_{table}_keys`` (uint64) / ``_vals`` (int64).
    """
    p, t = ev.panoptic, ev.lstq
    partials = [list(s._partials) for s in p._iou]
    out: dict[str, np.ndarray] = {
        "meta": np.array([ev.min_points, p.frames, t.frames], dtype=np.int64),
        "mode": np.array(str(ev.mode)),
        "ignore": np.array(ev.spec.ignore, dtype=np.int64),
        "pq_conf": p.conf.copy(),
        "pq_tp": p.tp.copy(),
        "pq_fp": p.fp.copy(),
        "pq_fn": p.fn.copy(),
        "pq_partials": np.array([x for ps in partials for x in ps], dtype=np.float64),
        "pq_partials_len": np.array([len(ps) for ps in partials], dtype=np.int64),
        "lstq_conf": t.conf.copy(),
    }
    seqs = sorted(t.seqs)
    out["lstq_seqs"] = np.array(seqs, dtype=str)
    for i, seq in enumerate(seqs):
        for name in _TABLES:
            keys, vals = getattr(t.seqs[seq], name).items()
            out[f"lstq_{i}_{name}_keys"] = keys.copy()
            out[f"lstq_{i}_{name}_vals"] = vals.copy()
    return out


def restore_evaluator(label_map: LabelMap, state: dict[str, np.ndarray]) -> PanopticEvaluator:
    """An evaluator holding ``state`` (from :func:`evaluator_state`), ready to ``merge`` or ``result``."""
    meta = np.asarray(state["meta"])
    ev = PanopticEvaluator(
        label_map,
        min_points=int(meta[0]),
        mode=str(state["mode"]),
        keep_rows=False,
        ignore=tuple(int(i) for i in state["ignore"]),
    )
    p, t = ev.panoptic, ev.lstq
    if state["pq_conf"].shape != p.conf.shape:
        raise ValueError(f"state has {state['pq_conf'].shape[0]} classes, label map {p.conf.shape[0]}")
    p.conf[:] = state["pq_conf"]
    p.tp[:] = state["pq_tp"]
    p.fp[:] = state["pq_fp"]
    p.fn[:] = state["pq_fn"]
    flat = np.asarray(state["pq_partials"], dtype=np.float64)
    ends = np.cumsum(state["pq_partials_len"])
    for k, (a, b) in enumerate(zip(np.concatenate(([0], ends[:-1])), ends, strict=True)):
        s = ExactSum()
        s._partials = [float(x) for x in flat[a:b]]
        p._iou[k] = s
    p.frames = int(meta[1])
    t.conf[:] = state["lstq_conf"]
    t.frames = int(meta[2])
    for i, seq in enumerate(np.asarray(state["lstq_seqs"]).tolist()):
        tables = _SeqTables()
        for name in _TABLES:
            table = CountTable()
            table.add(state[f"lstq_{i}_{name}_keys"], state[f"lstq_{i}_{name}_vals"])
            setattr(tables, name, table)
        t.seqs[str(seq)] = tables
    return ev


def state_to_bytes(state: dict[str, np.ndarray]) -> bytes:
    """``.npz`` bytes of a state (no pickling)."""
    buf = io.BytesIO()
    np.savez(buf, **state)
    return buf.getvalue()


def state_from_bytes(data: bytes) -> dict[str, np.ndarray]:
    """Inverse of :func:`state_to_bytes` (``allow_pickle=False``)."""
    with np.load(io.BytesIO(data), allow_pickle=False) as npz:
        return {k: npz[k] for k in npz.files}
