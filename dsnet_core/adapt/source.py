"""The source half of every mixed pair: scans with true labels, from the synthetic stream (never
the same street twice; what a (round, epoch) draws depends on the seed only) or from a labelled
log. Also the fixed source probe the teacher is validated on (does adaptation forget the source?).
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from dsnet_core.adapt.data import Item, volumes
from dsnet_core.io.reader import LogReader
from dsnet_core.train.stream import StreamLog

ROUND_STAGE = 16
"""Stream windows of adaptation round r are those of stage ``16 + r`` (training uses 0..3)."""


class Source(Protocol):
    """Source items for a (round, epoch)."""

    def items(self, round: int, epoch: int, n: int) -> list[Item]: ...

    def record(self) -> dict: ...

    def close(self) -> None: ...


class StreamSource:
    """Never-seen samples of a :class:`~dsnet_core.train.stream.StreamLog` (its ``steps`` must be at
    least the pairs of any epoch)."""

    def __init__(self, stream: StreamLog, weight: float) -> None:
        self.stream, self.weight = stream, weight

    def items(self, round: int, epoch: int, n: int) -> list[Item]:
        names = self.stream.window(ROUND_STAGE + round, epoch)[:n]
        self.stream.prefetch(names)
        return [Item(self.stream, tuple(refs), self.weight, "source") for refs in self.stream.volumes(names)]

    def record(self) -> dict:
        return {"stream": self.stream.record()}

    def close(self) -> None:
        self.stream.close()


class LogSource:
    """A labelled log's volumes, in a seeded order per (round, epoch), cycled when ``n`` exceeds them."""

    def __init__(self, reader: LogReader, scans: int, weight: float, seed: int) -> None:
        self.reader, self.seed = reader, seed
        self.pool = volumes(reader, scans, weight, "source")
        if not self.pool:
            raise ValueError(f"the source log {reader.root} has no labelled frames")

    def items(self, round: int, epoch: int, n: int) -> list[Item]:
        rng = np.random.default_rng([self.seed, 41, round, epoch])
        return [self.pool[i] for i in cycled(rng, len(self.pool), n)]

    def record(self) -> dict:
        return {"log": str(self.reader.root), "volumes": len(self.pool)}

    def close(self) -> None:
        return None


def cycled(rng: np.random.Generator, size: int, n: int) -> list[int]:
    """``n`` indices into ``size`` items: seeded permutations, one after the other."""
    out: list[int] = []
    while len(out) < n:
        out.extend(rng.permutation(size).tolist())
    return out[:n]


def stream_probe(stream: StreamLog, count: int) -> list[Item]:
    """``count`` fixed stream samples (the stream's probe window) as validation items."""
    if count <= 0:
        return []
    names = stream.probe(count)
    return [Item(stream, tuple(refs), 1.0, "source") for refs in stream.volumes(names)]
