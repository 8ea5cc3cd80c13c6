"""Save and restore a :class:`~.nuscenes_scorer.NuScenesScorer`'s accumulators as plain numpy arrays.

As :mod:`.state` does for :class:`~.evaluator.PanopticEvaluator`: the score stage leaves one state
per block and the report merges them (a scene's blocks in order). Exact: a restored and merged
scorer gives a one-pass scorer's results bit for bit (sums as Shewchuk partials, counts as
integers, per-scene tracks and last-frame matches as arrays, scenes and tracks in insertion order
since TQ sums over them in that order).
"""

from __future__ import annotations

import numpy as np

from .cells import CountTable, ExactSum
from .nuscenes_scorer import ClassSet, NuScenesScorer
from .nuscenes_track import PanopticTrackingAccumulator, _Scene, _Track
from .panoptic import Matches
from .state import _lstq_tables_state, _pq_state, _restore_lstq_tables, _restore_pq

KIND = "panoptic-nuscenes"


def _sums_state(sums: list[ExactSum], key: str) -> dict[str, np.ndarray]:
    parts = [list(s._partials) for s in sums]
    return {
        key: np.array([x for ps in parts for x in ps], dtype=np.float64),
        f"{key}_len": np.array([len(ps) for ps in parts], dtype=np.int64),
    }


def _restore_sums(state: dict[str, np.ndarray], key: str) -> list[ExactSum]:
    flat = np.asarray(state[key], dtype=np.float64)
    ends = np.cumsum(state[f"{key}_len"])
    out = []
    for a, b in zip(np.concatenate(([0], ends[:-1])), ends, strict=True):
        s = ExactSum()
        s._partials = [float(x) for x in flat[a:b]]
        out.append(s)
    return out


def _matches_state(m: Matches | None, key: str) -> dict[str, np.ndarray]:
    if m is None:
        return {}
    return {f"{key}_{f}": np.asarray(getattr(m, f)).copy() for f in ("cls", "gt", "pred", "iou")}


def _restore_matches(state: dict[str, np.ndarray], key: str) -> Matches | None:
    if f"{key}_cls" not in state:
        return None
    return Matches(*(np.asarray(state[f"{key}_{f}"]) for f in ("cls", "gt", "pred", "iou")))


def tracking_state(acc: PanopticTrackingAccumulator, prefix: str) -> dict[str, np.ndarray]:
    """The state of a tracking accumulator under ``prefix``."""
    out = {**_pq_state(acc.pq, f"{prefix}pq_"), f"{prefix}ids": acc.ids.copy()}
    out.update(_sums_state(acc._soft, f"{prefix}soft"))
    out[f"{prefix}lstq_frames"] = np.array(acc.lstq.frames, dtype=np.int64)
    lstq_seqs = sorted(acc.lstq.seqs)
    out[f"{prefix}lstq_seqs"] = np.array(lstq_seqs, dtype=str)
    for i, seq in enumerate(lstq_seqs):
        out.update(_lstq_tables_state(acc.lstq.seqs[seq], f"{prefix}lstq{i}_"))
    scenes = list(acc.scenes)  # insertion order: TQ sums tracks in it
    out[f"{prefix}scenes"] = np.array(scenes, dtype=str)
    for i, name in enumerate(scenes):
        s, key = acc.scenes[name], f"{prefix}scene{i}_"
        out.update(_matches_state(s.first, f"{key}first"))
        out.update(_matches_state(s.last, f"{key}last"))
        keys, vals = s.pred_frames.items()
        out[f"{key}pf_keys"], out[f"{key}pf_vals"] = keys.copy(), vals.copy()
        gts = list(s.tracks)
        tracks = [s.tracks[g] for g in gts]
        out[f"{key}tracks"] = np.array(
            [[g, t.length, t.switches, t.first, t.last] for g, t in zip(gts, tracks, strict=True)],
            dtype=np.int64,
        ).reshape(-1, 5)
        counts = [(j, k, v) for j, t in enumerate(tracks) for k, v in sorted(t.counts.items())]
        out[f"{key}counts"] = np.array(counts, dtype=np.int64).reshape(-1, 3)
    return out


def restore_tracking(acc: PanopticTrackingAccumulator, state: dict[str, np.ndarray], prefix: str) -> None:
    """Load a state written by :func:`tracking_state` into a fresh accumulator of the same classes."""
    _restore_pq(acc.pq, state, f"{prefix}pq_")
    acc.ids[:] = state[f"{prefix}ids"]
    acc._soft = _restore_sums(state, f"{prefix}soft")
    acc.lstq.frames = int(state[f"{prefix}lstq_frames"])
    for i, seq in enumerate(np.asarray(state[f"{prefix}lstq_seqs"]).tolist()):
        acc.lstq.seqs[str(seq)] = _restore_lstq_tables(acc.spec.n_classes, state, f"{prefix}lstq{i}_")
    for i, name in enumerate(np.asarray(state[f"{prefix}scenes"]).tolist()):
        key = f"{prefix}scene{i}_"
        s = _Scene(_restore_matches(state, f"{key}first"), _restore_matches(state, f"{key}last"))
        s.pred_frames = CountTable()
        s.pred_frames.add(state[f"{key}pf_keys"], state[f"{key}pf_vals"])
        rows = np.asarray(state[f"{key}tracks"]).reshape(-1, 5).tolist()
        tracks = [_Track(int(n), int(sw), int(a), int(b), {}) for _, n, sw, a, b in rows]
        for j, k, v in np.asarray(state[f"{key}counts"]).reshape(-1, 3).tolist():
            tracks[j].counts[int(k)] = int(v)
        s.tracks = {int(r[0]): t for r, t in zip(rows, tracks, strict=True)}
        acc.scenes[str(name)] = s


def scorer_state(scorer: NuScenesScorer) -> dict[str, np.ndarray]:
    """The accumulator state of a nuScenes scorer (``np.savez`` ready; no pickling)."""
    out: dict[str, np.ndarray] = {
        "kind": np.array(KIND),
        "mapping_sha256": np.array(scorer.mapping.sha256),
        "min_points": np.array(scorer.min_points, dtype=np.int64),
    }
    for name in ("all", "expressible"):
        cs: ClassSet = getattr(scorer, name)
        out.update(_pq_state(cs.seg, f"{name}_seg_"))
        out.update(tracking_state(cs.track, f"{name}_track_"))
    return out


def restore_scorer(fresh: NuScenesScorer, state: dict[str, np.ndarray]) -> NuScenesScorer:
    """Load ``state`` into ``fresh`` (a new scorer with the same maps, mapping and min_points).

    Raises:
        ValueError: the state is not a nuScenes scorer's, or was made with another mapping or
            min_points.
    """
    if str(state.get("kind", "")) != KIND:
        raise ValueError(f"not a {KIND} scorer state")
    if str(state["mapping_sha256"]) != fresh.mapping.sha256 or int(state["min_points"]) != fresh.min_points:
        raise ValueError("the state was scored with another class mapping or min_points")
    for name in ("all", "expressible"):
        cs: ClassSet = getattr(fresh, name)
        _restore_pq(cs.seg, state, f"{name}_seg_")
        restore_tracking(cs.track, state, f"{name}_track_")
    return fresh
