"""A method is an ordered list of stages: :class:`Pipeline`.

The runner, the flows and the report take a pipeline as an argument. A test adds a stage by
building its own pipeline; a method (:mod:`tasks.methods`) builds its pipeline from its stages.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

from tasks.base import FRAME_LABEL, Stage

OPTIONAL_STAGES = {"refine": "--no-refine"}
"""Stages a method option leaves out of a pipeline, and the option that does."""


@dataclass(frozen=True)
class Pipeline:
    """Stages in run order, every stage after its upstream stages.

    Attributes:
        name: the method's name (recorded in the run config).
        stages: the stages, in run order.
        labels: the stage whose per-frame ``label`` array (uint32, raw semantic | id << 16, in each
            scan's point order) holds the method's final labels: what ``export`` and ``score`` read.
        options: the options the method's factory was called with (recorded in the run config).
    """

    name: str
    stages: tuple[Stage, ...]
    labels: str
    options: tuple[tuple[str, object], ...] = ()

    def __post_init__(self) -> None:
        seen: list[str] = []
        for stage in self.stages:
            if stage.name in seen:
                raise ValueError(f"pipeline {self.name!r}: stage {stage.name!r} appears twice")
            missing = [u for u in stage.upstream if u not in seen]
            if missing:
                raise ValueError(
                    f"pipeline {self.name!r}: stage {stage.name!r} reads {missing}, not run before it"
                )
            seen.append(stage.name)
        for stage in self.stages:
            stage.check_sources(self)
            for source, arrays in stage.reads(self).items():
                covered = {n for u in stage.upstream for n in (u, *self.upstream_closure(u))}
                if source not in covered:
                    raise ValueError(
                        f"pipeline {self.name!r}: stage {stage.name!r} reads {source!r}, which is not "
                        "upstream of what it reads (its fingerprint would not cover it)"
                    )
                stage.require(self, source, arrays)
        if self.labels not in seen:
            raise ValueError(f"pipeline {self.name!r}: its labels stage {self.labels!r} is not one of {seen}")
        if FRAME_LABEL not in self[self.labels].arrays:
            raise ValueError(f"pipeline {self.name!r}: stage {self.labels!r} declares no FRAME_LABEL array")

    def __getitem__(self, name: str) -> Stage:
        for stage in self.stages:
            if stage.name == name:
                return stage
        raise KeyError(f"pipeline {self.name!r} has no stage {name!r}; stages are {self.names()}")

    def __contains__(self, name: object) -> bool:
        return any(stage.name == name for stage in self.stages)

    def __iter__(self) -> Iterator[Stage]:
        return iter(self.stages)

    def names(self) -> list[str]:
        return [stage.name for stage in self.stages]

    def check_stage(self, name: str | None) -> None:
        """Raise ValueError naming the stages when ``name`` (if given) is not one of them."""
        if name is not None and name not in self:
            if name in OPTIONAL_STAGES and dict(self.options).get(name) is False:
                raise ValueError(
                    f"stage {name!r} is off in this run ({OPTIONAL_STAGES[name]}): its stages are "
                    f"{self.names()}; drop the option to run {name}, or name one of these"
                )
            raise ValueError(f"unknown stage {name!r}; stages are {self.names()}")

    def until(self, name: str | None) -> list[str]:
        """Stage names up to and including ``name`` (all when None)."""
        self.check_stage(name)
        names = self.names()
        return names if name is None else names[: names.index(name) + 1]

    def downstream_of(self, name: str) -> list[str]:
        """Stages that read ``name`` directly or indirectly, in order."""
        out: list[str] = []
        for stage in self.stages:
            if any(u == name or u in out for u in stage.upstream):
                out.append(stage.name)
        return out

    def upstream_closure(self, name: str) -> list[str]:
        """Stages ``name`` reads directly or indirectly, in run order."""
        need = set(self[name].upstream)
        for stage in reversed(self.stages):
            if stage.name in need:
                need.update(stage.upstream)
        return [n for n in self.names() if n in need]

    def record(self) -> dict[str, object]:
        """What the run config records of the method."""
        return {
            "method": self.name,
            "method_options": dict(self.options),
            "stage_versions": {s.name: s.version for s in self.stages},
            "labels_stage": self.labels,
        }
