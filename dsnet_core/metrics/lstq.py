"""LSTQ = sqrt(S_assoc · S_cls): a streaming, mergeable accumulator.

Two association rules share the machinery (see docs/metrics.md):

* ``4dpls`` — the SemanticKITTI 4D benchmark (4D-PLS ``Panoptic4DEval``): class-agnostic ids
  ``v >> 16``; predicted sizes in one table per sequence over predicted classes 1..C-1 (stuff
  included); gt tubes per (sequence, class) fed by frames where the id has > min_points points;
  S_assoc's numerator sums all classes, its denominator counts thing tubes only; S_cls divides
  by the classes with a non-zero union, class 0 included.
* ``nuscenes`` — the Panoptic nuScenes tracking evaluator: only thing classes; ids are whole
  panoptic labels; predicted sizes also need > min_points per frame and class; S_cls is the
  mean IoU over the scored classes, absent classes 0.

``corrected`` mode (4dpls) fixes the documented defects: ids count on thing classes only (in
ground truth and prediction), a gt instance with ≤ min_points points in a frame is dropped from
everything in that frame (prediction sizes too), S_assoc averages thing tubes over thing tubes,
and S_cls ignores class 0. Ground truth scored against itself then gives S_assoc = 1.

Memory: per sequence, tables keyed by tube, predicted id and (tube, predicted id): bounded by
segments, never by points or frames.
"""

from __future__ import annotations

import math

import numpy as np

from .cells import Cells, CountTable
from .decode import ClassSpec
from .panoptic import semantic_iou
from .report import LSTQResult, Mode, as_mode

VARIANTS = ("4dpls", "nuscenes")
_ID_BITS = 24  # ids < 2**24 (SemanticKITTI ids < 2**16, nuScenes labels < 2**16)
_U = np.uint64


class _SeqTables:
    __slots__ = ("conf", "inter", "preds", "tubes")

    def __init__(self, n_classes: int) -> None:
        self.conf = np.zeros((n_classes, n_classes), dtype=np.int64)  # conf[pred, gt], all points
        self.preds = CountTable()  # pred id -> points
        self.tubes = CountTable()  # cls << 24 | gt id -> points
        self.inter = CountTable()  # (cls << 24 | gt id) << 24 | pred id -> points

    def compact(self) -> None:
        self.preds.compact()
        self.tubes.compact()
        self.inter.compact()

    def merge(self, other: _SeqTables) -> None:
        self.conf += other.conf
        self.preds.merge(other.preds)
        self.tubes.merge(other.tubes)
        self.inter.merge(other.inter)

    def state(self, prefix: str) -> dict[str, np.ndarray]:
        out = {f"{prefix}conf": self.conf.copy()}
        for name in _TABLES:
            out.update(getattr(self, name).state(f"{prefix}{name}"))
        return out

    @classmethod
    def from_state(cls, n_classes: int, state: dict[str, np.ndarray], prefix: str) -> _SeqTables:
        t = cls(n_classes)
        t.conf[:] = state[f"{prefix}conf"]
        for name in _TABLES:
            setattr(t, name, CountTable.from_state(state, f"{prefix}{name}"))
        return t


_TABLES = ("preds", "tubes", "inter")


class LSTQAccumulator:
    """Accumulates the association tables and the semantic confusion matrix.

    Args:
        spec: the scored classes.
        min_points: a gt id contributes to its tube in a frame only with > min_points points.
        mode: ``official`` or ``corrected`` (``corrected`` applies to the ``4dpls`` variant).
        variant: ``4dpls`` (SemanticKITTI 4D) or ``nuscenes`` (Panoptic nuScenes tracking).
    """

    def __init__(
        self,
        spec: ClassSpec,
        min_points: int = 50,
        mode: Mode | str = Mode.OFFICIAL,
        variant: str = "4dpls",
    ) -> None:
        if variant not in VARIANTS:
            raise ValueError(f"unknown LSTQ variant {variant!r}: use one of {VARIANTS}")
        self.spec = spec
        self.min_points = int(min_points)
        self.mode = as_mode(mode)
        self.variant = variant
        self._ignored = spec.mask(spec.ignore)
        self._include = ~self._ignored
        self._thing = spec.mask(spec.things)
        self.seqs: dict[str, _SeqTables] = {}
        self.frames = 0
        self._active: str | None = None  # only the sequence being added to keeps buffered rows

    @property
    def conf(self) -> np.ndarray:
        """``(C, C) int64`` semantic confusion ``conf[pred, gt]`` over all sequences."""
        c = self.spec.n_classes
        return sum((t.conf for t in self.seqs.values()), np.zeros((c, c), dtype=np.int64))

    # -- accumulation ---------------------------------------------------------------------
    def add(self, cells: Cells, sequence: str) -> None:
        """Add one frame of ``sequence`` given its cells."""
        c = self.spec.n_classes
        if cells.count.size and (max(cells.gt_cls.max(), cells.pred_cls.max()) >= c):
            raise ValueError(f"class ids must be < {c}")
        if cells.count.size and max(cells.gt_id.max(), cells.pred_id.max()) >= 1 << _ID_BITS:
            raise ValueError(f"instance ids must be < 2**{_ID_BITS}")
        conf = np.bincount(cells.pred_cls * c + cells.gt_cls, weights=cells.count, minlength=c * c)
        sequence = str(sequence)
        if self._active is not None and self._active != sequence and self._active in self.seqs:
            self.seqs[self._active].compact()
        self._active = sequence
        tables = self.seqs.setdefault(sequence, _SeqTables(c))
        tables.conf += conf.astype(np.int64).reshape(c, c)
        cl = cells.select(~self._ignored[cells.gt_cls])
        if self.variant == "nuscenes":
            self._add_nuscenes(cl, tables)
        elif self.mode is Mode.OFFICIAL:
            self._add_4dpls(cl, tables, cl.gt_id, cl.pred_id, self._include)
        else:
            gid = np.where(self._thing[cl.gt_cls], cl.gt_id, 0)
            pid = np.where(self._thing[cl.pred_cls], cl.pred_id, 0)
            tube, n = _group(_tube_key(cl.gt_cls, gid), cl.count, gid != 0)
            small = tube[n <= self.min_points]
            keep = ~np.isin(_tube_key(cl.gt_cls, gid), small) | (gid == 0)
            cl = cl.select(keep)
            self._add_4dpls(cl, tables, gid[keep], pid[keep], self._thing)
        self.frames += 1

    def _add_4dpls(
        self, cl: Cells, t: _SeqTables, gid: np.ndarray, pid: np.ndarray, tube_cls: np.ndarray
    ) -> None:
        pm = self._include[cl.pred_cls] & (pid != 0)
        t.preds.add(pid[pm].astype(_U), cl.count[pm])
        self._add_tubes(cl, t, gid, pid, tube_cls[cl.gt_cls] & (gid != 0), pid != 0)

    def _add_nuscenes(self, cl: Cells, t: _SeqTables) -> None:
        # predicted sizes: per frame and thing class, ids with > min_points points
        pm = self._thing[cl.pred_cls]
        keys, n = _group(cl.pred_id.astype(_U), cl.count, pm)
        big = n > self.min_points
        t.preds.add(keys[big], n[big])
        self._add_tubes(cl, t, cl.gt_id, cl.pred_id, self._thing[cl.gt_cls], np.ones(cl.count.size, bool))

    def _add_tubes(
        self,
        cl: Cells,
        t: _SeqTables,
        gid: np.ndarray,
        pid: np.ndarray,
        gm: np.ndarray,
        pred_ok: np.ndarray,
    ) -> None:
        tkey = _tube_key(cl.gt_cls, gid)
        keys, n = _group(tkey, cl.count, gm)
        big = n > self.min_points
        t.tubes.add(keys[big], n[big])
        im = gm & np.isin(tkey, keys[big]) & pred_ok
        t.inter.add((tkey[im] << _U(_ID_BITS)) | pid[im].astype(_U), cl.count[im])

    def merge(self, other: LSTQAccumulator) -> LSTQAccumulator:
        """Add ``other``'s tables into this accumulator; returns self.

        Frames of one sequence may be split across accumulators in any way.
        """
        same = (other.spec, other.min_points, other.mode, other.variant)
        if same != (self.spec, self.min_points, self.mode, self.variant):
            raise ValueError("cannot merge accumulators with different classes, min_points, mode or variant")
        for seq, tables in other.seqs.items():
            self.seqs.setdefault(seq, _SeqTables(self.spec.n_classes)).merge(tables)
        self.frames += other.frames
        return self

    # -- state --------------------------------------------------------------------------------
    def state(self, prefix: str = "") -> dict[str, np.ndarray]:
        """The exact state as named arrays under ``prefix``: frames, the sequence names (sorted)
        and each sequence's tables under ``{prefix}{i}_``."""
        seqs = sorted(self.seqs)
        out = {
            f"{prefix}frames": np.array(self.frames, dtype=np.int64),
            f"{prefix}seqs": np.array(seqs, dtype=str),
        }
        for i, seq in enumerate(seqs):
            out.update(self.seqs[seq].state(f"{prefix}{i}_"))
        return out

    def restore(self, state: dict[str, np.ndarray], prefix: str = "") -> LSTQAccumulator:
        """Load a :meth:`state` of an accumulator with the same settings; returns self."""
        self.frames = int(state[f"{prefix}frames"])
        c = self.spec.n_classes
        for i, seq in enumerate(np.asarray(state[f"{prefix}seqs"]).reshape(-1).tolist()):
            self.seqs[str(seq)] = _SeqTables.from_state(c, state, f"{prefix}{i}_")
        return self

    # -- results --------------------------------------------------------------------------
    def association(self, sequences: list[str] | None = None) -> tuple[float, int, np.ndarray]:
        """``(numerator, thing tubes, per-class numerator (C,))`` of S_assoc (all or some sequences)."""
        c = self.spec.n_classes
        total = 0.0
        per_class = np.zeros(c, dtype=np.float64)
        n_thing = 0
        for seq in sorted(self.seqs if sequences is None else sequences):
            t = self.seqs[seq]
            tkeys, tsize = t.tubes.items()
            pkeys, psize = t.preds.items()
            ikeys, tpa = t.inter.items()
            tcls = (tkeys >> _U(_ID_BITS)).astype(np.int64)
            n_thing += int(self._thing[tcls].sum())
            if not ikeys.size or not tkeys.size:
                continue
            it = np.searchsorted(tkeys, ikeys >> _U(_ID_BITS))
            pid = ikeys & _U((1 << _ID_BITS) - 1)
            if not pkeys.size:
                continue
            ip = np.minimum(np.searchsorted(pkeys, pid), pkeys.size - 1)
            found = pkeys[ip] == pid
            g = tsize[it[found]].astype(np.float64)
            p = psize[ip[found]].astype(np.float64)
            a = tpa[found].astype(np.float64)
            contrib = a * (a / (g + p - a)) / g
            per_tube = np.bincount(it[found], weights=contrib, minlength=tkeys.size)
            per_class += np.bincount(tcls, weights=per_tube, minlength=c)
            total += math.fsum(per_tube)
        return total, n_thing, per_class

    def result(self, sequence: str | None = None) -> LSTQResult:
        """LSTQ and its parts so far, over all sequences or one (idempotent: the state is not changed)."""
        spec = self.spec
        if sequence is not None and sequence not in self.seqs:
            raise KeyError(f"no frames of sequence {sequence!r} were scored")
        num, n_thing, _ = self.association(None if sequence is None else [sequence])
        with np.errstate(divide="ignore", invalid="ignore"):
            s_assoc = float(np.float64(num) / np.float64(n_thing))
        conf = self.conf if sequence is None else self.seqs[sequence].conf
        iou, union = semantic_iou(conf, spec.ignore)
        inc = spec.include
        if self.variant == "nuscenes":
            s_cls = float(iou[inc].mean())
        elif self.mode is Mode.OFFICIAL:
            present = np.count_nonzero(union)
            s_cls = float(np.sum(iou) / present) if present else float("nan")
        else:
            present = union[inc] > 0
            s_cls = float(iou[inc][present].mean()) if present.any() else float("nan")
        prod = s_assoc * s_cls
        lstq = math.sqrt(prod) if prod >= 0 else float("nan")
        th, st = list(spec.things), list(spec.stuff)
        return LSTQResult(
            mode=self.mode,
            lstq=lstq,
            s_assoc=s_assoc,
            s_cls=s_cls,
            iou_things=float(iou[th].mean()) if th else float("nan"),
            iou_stuff=float(iou[st].mean()) if st else float("nan"),
            n_tubes=n_thing,
            per_class_iou={spec.names[k]: float(iou[k]) for k in inc},
        )


def _tube_key(cls: np.ndarray, ids: np.ndarray) -> np.ndarray:
    return (cls.astype(_U) << _U(_ID_BITS)) | ids.astype(_U)


def _group(keys: np.ndarray, counts: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sum ``counts`` by ``keys`` over ``mask``: ``(unique keys (M,) uint64, sums (M,) int64)``."""
    k, inv = np.unique(keys[mask], return_inverse=True)
    return k, np.bincount(inv, weights=counts[mask], minlength=k.size).astype(np.int64)


__all__ = ["VARIANTS", "LSTQAccumulator"]
