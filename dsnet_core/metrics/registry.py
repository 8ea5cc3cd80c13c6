"""Metrics: one registry through which every scorer, table and page finds what to compute and show.

A metric is one module that calls :func:`register` with a :class:`Metric`: its name, the columns
it reports (run- and sequence-level values, per-class values, per-frame values) and ``make``, which
builds its accumulator for a scorer's :class:`Setup` (or returns None where the metric does not
apply, e.g. the Panoptic nuScenes tracking metrics on SemanticKITTI ground truth). An accumulator
(:class:`MetricAccumulator`) owns its state: it adds frames, merges with another of the same
setup, saves and restores its state as plain arrays, and returns ``dict[str, float]`` plus
per-class rows. Scorers (:mod:`.evaluator`, :mod:`.nuscenes_scorer`) hold one
:class:`MetricSet`; the score stage's table, the report tables, the dashboard, ``dsnet eval`` and
``serve``'s summary take their columns from :func:`columns` and print the keys they get.

The built-in metrics are registered at the end of this module, in the order tables show them:
``panoptic`` (PQ family, mIoU), ``lstq``, ``nuscenes_tracking`` (PAT, TQ, PTQ, sPTQ),
``expressible`` (nuScenes numbers over the classes the model can express) and ``present`` (means
over the classes present, :mod:`.present`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal, Protocol

import numpy as np

from .cells import Cells
from .decode import ClassSpec
from .panoptic import FramePQ
from .report import Mode

STATE_FORMAT = "2"
"""Version of a scorer state's layout (1: the fixed layout before this registry, refused)."""


@dataclass(frozen=True)
class Column:
    """One value a metric reports.

    Attributes:
        key: the column name in tables and JSON (unique over the registry, per level).
        label: a short label for tables and pages (``mIoU (present)``).
        kind: ``score`` (a fraction in [0, 1], shown in percent; float64) or ``count`` (int64).
        brief: one of the few numbers shown where little fits (dashboard cards, the sequences
            table, serve's summary line, ``publish``'s headline).
        help: one line saying what it is.
    """

    key: str
    label: str
    kind: Literal["score", "count"] = "score"
    brief: bool = False
    help: str = ""


@dataclass(frozen=True)
class Setup:
    """What a scorer gives every metric to build its accumulator.

    Attributes:
        spec: the scored classes (the ground truth's benchmark classes).
        min_points: minimum segment size.
        mode: ``official`` or ``corrected``.
        benchmark: ``semantic-kitti`` (SemanticKITTI semantics: every same-map scorer) or
            ``panoptic-nuscenes``.
        expressible: nuScenes: the classes the model's classes can express (others ignored).
    """

    spec: ClassSpec
    min_points: int
    mode: Mode
    benchmark: str = "semantic-kitti"
    expressible: ClassSpec | None = None


@dataclass(frozen=True)
class Frame:
    """One scored frame as every metric sees it.

    Attributes:
        cells: the frame's (gt, pred) label cells (:mod:`.cells`).
        sequence: the sequence (or scene) name; frames of a sequence arrive in time order.
        pq: the frame's PQ counts and confusion over ``Setup.spec`` (official float64 matching),
            computed once by the scorer.
    """

    cells: Cells
    sequence: str
    pq: FramePQ


class MetricAccumulator(Protocol):
    """A metric's streaming state. ``values``/``class_values`` never change the state."""

    def add(self, frame: Frame) -> dict[str, float]:
        """Add a frame; returns its per-frame values (the metric's ``frame_columns``)."""

    def merge(self, other: MetricAccumulator) -> None:
        """Add ``other``'s state (same setup; for a sequence split in chunks, a later chunk)."""

    def state(self) -> dict[str, np.ndarray]:
        """The exact state as named arrays (``np.savez`` ready, no pickling)."""

    def restore(self, state: dict[str, np.ndarray]) -> None:
        """Load a :meth:`state` into this fresh accumulator (raise ValueError if it does not fit)."""

    def values(self) -> dict[str, float]:
        """The run-level values (the metric's ``columns``)."""

    def class_values(self) -> dict[str, dict[str, float]]:
        """Per class name, the metric's ``class_columns`` (empty when it has none)."""


class OneAccumulator:
    """A metric whose whole state is one accumulator ``self.acc`` (with ``merge``, ``state`` and
    ``restore`` of its own): those three delegate to it."""

    acc: Any

    def merge(self, other: OneAccumulator) -> None:
        self.acc.merge(other.acc)

    def state(self) -> dict[str, np.ndarray]:
        return self.acc.state()

    def restore(self, state: dict[str, np.ndarray]) -> None:
        self.acc.restore(state)


@dataclass(frozen=True)
class Metric:
    """A registered metric.

    Attributes:
        name: registry key (also the prefix of its arrays in a saved scorer state).
        make: ``make(setup) -> accumulator``, or None where the metric does not apply.
        columns: run- and sequence-level values.
        class_columns: per-class values.
        frame_columns: per-frame values (the score stage's ``frame_metrics`` columns).
        title: a heading for ``dsnet eval``'s table of this metric.
    """

    name: str
    make: Callable[[Setup], MetricAccumulator | None]
    columns: tuple[Column, ...] = ()
    class_columns: tuple[Column, ...] = ()
    frame_columns: tuple[Column, ...] = ()
    title: str = ""


METRICS: dict[str, Metric] = {}


def register(metric: Metric) -> Metric:
    """Add (or replace) a metric; its keys must not clash with another metric's at any level.

    Raises:
        ValueError: a key another registered metric already reports.
    """
    for level in ("columns", "class_columns", "frame_columns"):
        mine = {c.key for c in getattr(metric, level)}
        for other in METRICS.values():
            if other.name != metric.name and mine & {c.key for c in getattr(other, level)}:
                clash = sorted(mine & {c.key for c in getattr(other, level)})
                raise ValueError(
                    f"metric {metric.name!r}: {level} {clash} already reported by {other.name!r}"
                )
    METRICS[metric.name] = metric
    return metric


def columns(level: Literal["run", "class", "frame"] = "run") -> list[Column]:
    """Every registered metric's columns of one level, in registration order."""
    attr = {"run": "columns", "class": "class_columns", "frame": "frame_columns"}[level]
    return [c for m in METRICS.values() for c in getattr(m, attr)]


def registry_digest() -> str:
    """Names and keys of the registered metrics (a stage fingerprint input: a new metric rescores)."""
    return ";".join(
        f"{m.name}:" + ",".join(c.key for c in (*m.columns, *m.class_columns, *m.frame_columns))
        for m in METRICS.values()
    )


class MetricSet:
    """The accumulators of every registered metric that applies to a setup, in registry order."""

    def __init__(self, setup: Setup) -> None:
        self.setup = setup
        self.accs: dict[str, MetricAccumulator] = {}
        for m in METRICS.values():
            acc = m.make(setup)
            if acc is not None:
                self.accs[m.name] = acc

    def __getitem__(self, name: str) -> MetricAccumulator:
        return self.accs[name]

    def __contains__(self, name: object) -> bool:
        return name in self.accs

    def metrics(self) -> list[Metric]:
        """The registered metrics this set holds."""
        return [METRICS[n] for n in self.accs]

    def add(self, frame: Frame) -> dict[str, float]:
        out: dict[str, float] = {}
        for acc in self.accs.values():
            out.update(acc.add(frame))
        return out

    def merge(self, other: MetricSet) -> None:
        if list(other.accs) != list(self.accs):
            raise ValueError(f"cannot merge metric sets {list(other.accs)} and {list(self.accs)}")
        for name, acc in self.accs.items():
            acc.merge(other.accs[name])

    def values(self) -> dict[str, float]:
        out: dict[str, float] = {}
        for acc in self.accs.values():
            out.update(acc.values())
        return out

    def class_values(self) -> dict[str, dict[str, float]]:
        out: dict[str, dict[str, float]] = {}
        for acc in self.accs.values():
            for name, row in acc.class_values().items():
                out.setdefault(name, {}).update(row)
        return out

    def copy(self) -> MetricSet:
        """A new set of the same setup holding this one's state."""
        out = MetricSet(self.setup)
        out.merge(self)
        return out

    def header(self) -> dict[str, np.ndarray]:
        """``format`` (:data:`STATE_FORMAT`) and ``metrics`` (the names, in order) of a state."""
        return {"format": np.array(STATE_FORMAT), "metrics": np.array(list(self.accs), dtype=str)}

    def state(self, prefix: str = "") -> dict[str, np.ndarray]:
        """Each metric's arrays under ``{prefix}{name}/`` (with :meth:`header`: a whole state)."""
        out: dict[str, np.ndarray] = {}
        for name, acc in self.accs.items():
            out.update({f"{prefix}{name}/{k}": v for k, v in acc.state().items()})
        return out

    def check(self, state: dict[str, np.ndarray], where: str = "scorer state") -> None:
        """Refuse a state whose :meth:`header` does not fit this set.

        Raises:
            ValueError: a state of another layout (format 1, before this registry) or of another
                set of metrics (a metric registered or removed since): score the frames again.
        """
        fmt = str(state["format"]) if "format" in state else "1"
        if fmt != STATE_FORMAT:
            raise ValueError(
                f"{where}: layout {fmt}, this version reads layout {STATE_FORMAT} (the metric registry); "
                "score the frames again (`dsnet label` reruns the score stage, whose version changed)"
            )
        saved = [str(n) for n in np.asarray(state["metrics"]).reshape(-1).tolist()]
        if saved != list(self.accs):
            raise ValueError(
                f"{where}: holds metrics {saved}, the registry now has {list(self.accs)}; "
                "score the frames again (`dsnet label` reruns the score stage)"
            )

    def restore(self, state: dict[str, np.ndarray], prefix: str = "") -> MetricSet:
        """Load the arrays :meth:`state` saved under ``prefix`` (call :meth:`check` first); returns self."""
        for name, acc in self.accs.items():
            pre = f"{prefix}{name}/"
            acc.restore({k[len(pre) :]: v for k, v in state.items() if k.startswith(pre)})
        return self


def _register_builtins() -> None:
    from .metric_lstq import LSTQ
    from .metric_nuscenes import EXPRESSIBLE, NUSCENES_TRACKING
    from .metric_panoptic import PANOPTIC
    from .present import PRESENT

    for metric in (PANOPTIC, LSTQ, NUSCENES_TRACKING, EXPRESSIBLE, PRESENT):
        register(metric)


_register_builtins()
