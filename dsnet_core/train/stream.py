"""Training from an endless stream of never-seen synthetic sequences (``dsnet train dsnet --stream N``).

:class:`StreamLog` is a read-only log (the :class:`~dsnet_core.io.reader.LogReader` protocol) whose
sequences are samples of :mod:`dsnet_core.synth.stream`, rendered in memory on demand. Every
(stage, epoch) of a run gets its own window of ``N`` stream steps (:meth:`StreamLog.window`), so no
street is seen twice and what an epoch sees is a function of (seed, stage, epoch) only: a resumed
run trains on exactly the samples an uninterrupted one would. A sample has k frames (the volume's
scans); its volume is the last frame with the k − 1 before it. With ``workers`` > 0, background
processes render the epoch's samples ahead in the order they will be read (:meth:`prefetch`);
the samples are identical to the serial ones.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import multiprocessing
import signal
import threading
from collections import OrderedDict
from collections.abc import Iterator
from concurrent.futures import Future, ProcessPoolExecutor
from pathlib import Path

import numpy as np

from dsnet_core.io.reader import FrameRef
from dsnet_core.labels import LabelMap, load_label_map
from dsnet_core.synth.stream import StreamOptions, StreamSample, stream_sample, stream_seed
from dsnet_core.synth.variation import choose_setup

STAGE_STRIDE = 1 << 32  # steps reserved per stage: windows of different stages never overlap
PROBE_BASE = 1 << 40  # the probe window (class counts at the start of a run)
PREFIX = "s"


class StreamLog:
    """A log whose sequence ``s<step>`` is stream sample ``step``.

    Args:
        seed: the stream's seed (the run's ``--seed``).
        options: frames per sample (= the volumes' k), styles and sensors drawn from.
        steps: samples per epoch.
        workers: background render processes (0: render when read).
        cache: rendered samples kept in memory.
    """

    format = "synth-stream"

    def __init__(
        self, seed: int, options: StreamOptions, steps: int, workers: int = 0, cache: int = 4
    ) -> None:
        if steps < 1:
            raise ValueError(f"--stream needs at least one sample per epoch, got {steps}")
        self.seed, self.options, self.steps, self.workers = seed, options, steps, workers
        # unknown style or sensor names fail here (ConfigError), not in a worker mid-epoch
        choose_setup(stream_seed(seed, 0), "random", "random", options.styles, options.sensors)
        self.root = Path(f"stream://seed-{seed}")
        self.label_map: LabelMap = load_label_map("semantic-kitti")
        self._cache: OrderedDict[int, StreamSample] = OrderedDict()
        self._cache_size = max(cache, options.frames)
        self._pending: dict[int, Future] = {}
        self._pool: ProcessPoolExecutor | None = None
        self._names: list[str] = []

    # -- windows ----------------------------------------------------------------------------
    def window(self, stage: int, epoch: int) -> list[str]:
        """The sequence names of (stage index, epoch): ``steps`` consecutive stream steps."""
        first = stage * STAGE_STRIDE + epoch * self.steps
        self._names = [f"{PREFIX}{first + i}" for i in range(self.steps)]
        return list(self._names)

    def probe(self, count: int = 16) -> list[str]:
        """A fixed window of ``min(count, steps)`` samples (class statistics of the stream)."""
        self._names = [f"{PREFIX}{PROBE_BASE + i}" for i in range(min(count, self.steps))]
        return list(self._names)

    def volumes(self, names: list[str]) -> list[list[FrameRef]]:
        """One volume per sample: its last frame with the k − 1 before it."""
        return [self.frames(n) for n in names]

    def prefetch(self, names: list[str]) -> None:
        """Start rendering ``names`` in the background, in this order (no-op without workers)."""
        if self.workers <= 0:
            return
        with sigint_ignored():  # workers spawned here ignore Ctrl-C: the parent stops them
            if self._pool is None:
                ctx = multiprocessing.get_context("spawn")
                self._pool = ProcessPoolExecutor(self.workers, mp_context=ctx)
            for name in names:
                step = _step(name)
                if step not in self._cache and step not in self._pending:
                    self._pending[step] = self._pool.submit(stream_sample, self.seed, step, self.options)

    def close(self) -> None:
        """Stop the background workers."""
        if self._pool is not None:
            if any(not f.done() for f in self._pending.values()):  # stopped mid-epoch (Ctrl-C)
                for process in list(getattr(self._pool, "_processes", {}).values()):
                    process.terminate()  # a sample in flight is not waited for: nothing uses it
            self._pool.shutdown(cancel_futures=True)
            self._pool = None
        self._pending.clear()

    def record(self) -> dict:
        """What the model card records of the stream."""
        o = self.options
        out = {
            "seed": self.seed,
            "samples_per_epoch": self.steps,
            "frames": o.frames,
            "styles": list(o.styles) if o.styles else "all",
            "sensors": list(o.sensors) if o.sensors else "all",
        }
        if o.config.variety != "base":  # base streams keep the record (and fingerprint) they had
            out["variety"] = o.config.variety
        if o.card is not None:
            out["sensor_card"] = o.card.model_dump(mode="json")
        return out

    def fingerprint(self) -> str:
        """sha256 of the stream's definition (seed, options, samples per epoch)."""
        text = json.dumps({**self.record(), "config": repr(self.options.config)}, sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()

    # -- the LogReader protocol ---------------------------------------------------------------
    def sequences(self) -> list[str]:
        return list(self._names)

    def frames(self, sequence: str) -> list[FrameRef]:
        step = _step(sequence)
        where = self.root / str(step)
        return [
            FrameRef(sequence, f"{i:06d}", i, where / f"{i:06d}.bin", where / f"{i:06d}.label")
            for i in range(self.options.frames)
        ]

    def scan(self, frame: FrameRef) -> np.ndarray:
        return self._sample(frame.sequence).scans[frame.index]

    def labels(self, frame: FrameRef) -> np.ndarray | None:
        return self._sample(frame.sequence).labels[frame.index]

    def pose(self, frame: FrameRef) -> np.ndarray | None:
        return self._sample(frame.sequence).poses[frame.index]

    def poses(self, sequence: str) -> np.ndarray | None:
        return self._sample(sequence).poses

    def timestamp(self, frame: FrameRef) -> float | None:
        return float(self._sample(frame.sequence).times[frame.index])

    def intensity_convention(self, sequence: str) -> str:
        return "unit"

    def setup(self, sequence: str) -> dict:
        """The sample's style, sensor and per-sequence draws."""
        return self._sample(sequence).setup

    def _sample(self, name: str) -> StreamSample:
        step = _step(name)
        if step in self._cache:
            self._cache.move_to_end(step)
            return self._cache[step]
        future = self._pending.pop(step, None)
        sample = future.result() if future is not None else stream_sample(self.seed, step, self.options)
        self._cache[step] = sample
        while len(self._cache) > self._cache_size:
            self._cache.popitem(last=False)
        return sample


@contextlib.contextmanager
def sigint_ignored() -> Iterator[None]:
    """Ignore SIGINT while worker processes are spawned (main thread only): a spawned interpreter
    that starts with SIGINT ignored keeps it ignored, so Ctrl-C reaches the parent alone (one line
    from the command) instead of a KeyboardInterrupt traceback from each worker."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def _step(name: str) -> int:
    if not name.startswith(PREFIX) or not name[len(PREFIX) :].isdigit():
        raise ValueError(f"not a stream sequence name: {name!r}")
    return int(name[len(PREFIX) :])
