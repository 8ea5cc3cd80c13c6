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
from .panoptic import PanopticAccumulator

_TABLES = ("preds", "tubes", "inter")


def _pq_state(acc: PanopticAccumulator, prefix: str) -> dict[str, np.ndarray]:
    partials = [list(s._partials) for s in acc._iou]
    return {
        f"{prefix}conf": acc.conf.copy(),
        f"{prefix}tp": acc.tp.copy(),
        f"{prefix}fp": acc.fp.copy(),
        f"{prefix}fn": acc.fn.copy(),
        f"{prefix}partials": np.array([x for ps in partials for x in ps], dtype=np.float64),
        f"{prefix}partials_len": np.array([len(ps) for ps in partials], dtype=np.int64),
        f"{prefix}frames": np.array(acc.frames, dtype=np.int64),
    }


def _restore_pq(acc: PanopticAccumulator, state: dict[str, np.ndarray], prefix: str) -> None:
    if state[f"{prefix}conf"].shape != acc.conf.shape:
        raise ValueError(
            f"state has {state[f'{prefix}conf'].shape[0]} classes, label map {acc.conf.shape[0]}"
        )
    acc.conf[:] = state[f"{prefix}conf"]
    acc.tp[:] = state[f"{prefix}tp"]
    acc.fp[:] = state[f"{prefix}fp"]
    acc.fn[:] = state[f"{prefix}fn"]
    flat = np.asarray(state[f"{prefix}partials"], dtype=np.float64)
    ends = np.cumsum(state[f"{prefix}partials_len"])
    for k, (a, b) in enumerate(zip(np.concatenate(([0], ends[:-1])), ends, strict=True)):
        s = ExactSum()
        s._partials = [float(x) for x in flat[a:b]]
        acc._iou[k] = s
    acc.frames = int(state[f"{prefix}frames"])


def evaluator_state(ev: PanopticEvaluator) -> dict[str, np.ndarray]:
    """The accumulator state of ``ev`` as named arrays (rows excluded).

    Keys: ``meta`` (int64 ``[min_points, frames_lstq]``), ``mode`` (str), ``ignore``; the panoptic
    accumulator under ``pq_*`` and each sequence's under ``pqseq{i}_*`` (``seqs`` names them);
    the LSTQ tables of sequence ``i`` under ``lstq_{i}_{conf|preds|tubes|inter}*``.
    """
    t = ev.lstq
    out: dict[str, np.ndarray] = {
        "meta": np.array([ev.min_points, t.frames], dtype=np.int64),
        "mode": np.array(str(ev.mode)),
        "ignore": np.array(ev.spec.ignore, dtype=np.int64),
        **_pq_state(ev.panoptic, "pq_"),
    }
    seqs = sorted(set(t.seqs) | set(ev.by_sequence))
    out["seqs"] = np.array(seqs, dtype=str)
    for i, seq in enumerate(seqs):
        if seq in ev.by_sequence:
            out.update(_pq_state(ev.by_sequence[seq], f"pqseq{i}_"))
        if seq in t.seqs:
            out.update(_lstq_tables_state(t.seqs[seq], f"lstq_{i}_"))
    return out


def _lstq_tables_state(tables: _SeqTables, prefix: str) -> dict[str, np.ndarray]:
    out = {f"{prefix}conf": tables.conf.copy()}
    for name in _TABLES:
        keys, vals = getattr(tables, name).items()
        out[f"{prefix}{name}_keys"] = keys.copy()
        out[f"{prefix}{name}_vals"] = vals.copy()
    return out


def _restore_lstq_tables(n_classes: int, state: dict[str, np.ndarray], prefix: str) -> _SeqTables:
    tables = _SeqTables(n_classes)
    tables.conf[:] = state[f"{prefix}conf"]
    for name in _TABLES:
        table = CountTable()
        table.add(state[f"{prefix}{name}_keys"], state[f"{prefix}{name}_vals"])
        setattr(tables, name, table)
    return tables


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
    _restore_pq(ev.panoptic, state, "pq_")
    t = ev.lstq
    t.frames = int(meta[1])
    c = ev.spec.n_classes
    for i, seq in enumerate(np.asarray(state["seqs"]).tolist()):
        if f"pqseq{i}_conf" in state:
            acc = PanopticAccumulator(ev.spec, ev.min_points, ev.mode)
            _restore_pq(acc, state, f"pqseq{i}_")
            ev.by_sequence[str(seq)] = acc
        if f"lstq_{i}_conf" in state:
            t.seqs[str(seq)] = _restore_lstq_tables(c, state, f"lstq_{i}_")
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
