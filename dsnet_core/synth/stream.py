"""A deterministic stream of never-seen synthetic sequences for training, fully in memory.

Sample ``step`` of a stream with ``seed`` is a short sequence whose street style and sensor are
drawn as in ``random`` mode (optionally from restricted lists, so styles or sensors can be held
out), rendered to scans, labels and poses without touching disk. It depends only on
``(seed, step)`` and the options, never on what was generated before, so a stream can resume at any
step and background workers return exactly what the serial loop returns.

Example::

    for sample in SynthStream(seed=0, frames=2, workers=2, styles=["residential", "country"]):
        scans, labels, poses = sample.scans, sample.labels, sample.poses
"""

from __future__ import annotations

import multiprocessing
from collections import deque
from collections.abc import Iterator
from concurrent.futures import Future, ProcessPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from dsnet_core.errors import ConfigError
from dsnet_core.sensor.card import SensorCard
from dsnet_core.synth.card_sensor import setup_from_card
from dsnet_core.synth.config import SynthConfig
from dsnet_core.synth.log import child_seed, plan_from_seed
from dsnet_core.synth.render import Renderer
from dsnet_core.synth.variation import choose_setup

STREAM_TAG = 0x5EED5  # keeps stream seeds apart from generate_log's (seed, sequence) seeds


@dataclass(frozen=True)
class StreamSample:
    """One streamed sequence.

    Attributes:
        step: its index in the stream.
        setup: its style, sensor and per-sequence draws (``SequenceSetup.record()``).
        scans: ``F`` arrays ``(N_i, 4) float32`` (x, y, z metres in the sensor frame; remission).
        labels: ``F`` arrays ``(N_i,) uint32`` (raw SemanticKITTI id | instance << 16).
        poses: ``(F, 4, 4) float64`` sensor poses relative to the first frame (first = identity).
        times: ``(F,) float64`` seconds from the first frame.
    """

    step: int
    setup: dict
    scans: list[np.ndarray]
    labels: list[np.ndarray]
    poses: np.ndarray
    times: np.ndarray


@dataclass(frozen=True)
class StreamOptions:
    """What a stream draws from.

    Attributes:
        frames: sweeps per sample.
        styles: street styles ``random`` draws from (None: all).
        sensors: LiDAR presets ``random`` draws from (None: all).
        config: world knobs.
        card: render every sample with this sensor card's LiDAR instead of a drawn preset
            (``dsnet train dsnet --stream-like LOG``; :mod:`dsnet_core.synth.card_sensor`).
    """

    frames: int = 2
    styles: tuple[str, ...] | None = None
    sensors: tuple[str, ...] | None = None
    config: SynthConfig = field(default_factory=SynthConfig)
    card: SensorCard | None = field(default=None, repr=False)


def stream_seed(seed: int, step: int) -> np.random.SeedSequence:
    """The sequence seed of sample ``step`` of the stream made with ``seed``."""
    if seed < 0 or step < 0:
        raise ConfigError(f"stream seed and step must be ≥ 0, got seed={seed}, step={step}")
    return np.random.SeedSequence([int(seed), int(step), STREAM_TAG])


def stream_sample(seed: int, step: int, options: StreamOptions | None = None) -> StreamSample:
    """Generate sample ``step`` of the stream made with ``seed`` (pure in its arguments).

    Raises:
        ConfigError: a negative seed or step, fewer than one frame, an unknown style or sensor.
    """
    options = options or StreamOptions()
    if options.frames < 1:
        raise ConfigError(f"a stream sample needs at least one frame, got frames={options.frames}")
    ss = stream_seed(seed, step)
    setup = choose_setup(child_seed(ss, 2), "random", "random", options.styles, options.sensors)
    if options.card is not None:
        setup = setup_from_card(options.card, setup.style)
    plan = plan_from_seed(ss, options.frames, options.config, setup, f"stream step {step}")
    renderer = Renderer(plan.scene, setup.spec, plan.poses[:, :2, 3])
    frame_seeds = child_seed(ss, 1).spawn(options.frames)
    scans, labels = [], []
    for i in range(options.frames):
        rng = np.random.default_rng(frame_seeds[i])
        scan, label = renderer.render(plan.poses[i], float(plan.times[i]), rng)
        scans.append(scan)
        labels.append(label)
    relative = np.linalg.inv(plan.poses[0])[None] @ plan.poses
    return StreamSample(step, setup.record(), scans, labels, relative, plan.times)


class SynthStream:
    """Iterates samples ``start, start + 1, …`` (``count`` of them, or forever) of a stream.

    With ``workers`` > 0 a process pool renders up to ``prefetch`` samples ahead; the samples and
    their order are exactly those of the serial iteration.

    Args:
        seed: the stream's seed.
        frames, styles, sensors, config: see :class:`StreamOptions`.
        start: first step.
        count: number of samples (None: endless).
        workers: background processes (0: render in the caller's process).
        prefetch: samples in flight (default ``2 · workers``).
    """

    def __init__(
        self,
        seed: int,
        frames: int = 2,
        styles: list[str] | tuple[str, ...] | None = None,
        sensors: list[str] | tuple[str, ...] | None = None,
        config: SynthConfig | None = None,
        start: int = 0,
        count: int | None = None,
        workers: int = 0,
        prefetch: int | None = None,
    ) -> None:
        self.seed, self.start, self.count, self.workers = seed, start, count, workers
        self.options = StreamOptions(
            frames,
            tuple(styles) if styles else None,
            tuple(sensors) if sensors else None,
            config or SynthConfig(),
        )
        self.prefetch = max(1, prefetch if prefetch is not None else 2 * workers)
        choose_setup(stream_seed(seed, start), "random", "random", self.options.styles, self.options.sensors)

    def _steps(self) -> Iterator[int]:
        step = self.start
        while self.count is None or step < self.start + self.count:
            yield step
            step += 1

    def __iter__(self) -> Iterator[StreamSample]:
        if self.workers <= 0:
            for step in self._steps():
                yield stream_sample(self.seed, step, self.options)
            return
        context = multiprocessing.get_context("spawn")  # no fork of a parent holding threads or CUDA
        with ProcessPoolExecutor(self.workers, mp_context=context) as pool:
            pending: deque[Future] = deque()
            steps = self._steps()
            for step in steps:
                pending.append(pool.submit(stream_sample, self.seed, step, self.options))
                if len(pending) >= self.prefetch:
                    break
            while pending:
                sample = pending.popleft().result()
                step = next(steps, None)
                if step is not None:
                    pending.append(pool.submit(stream_sample, self.seed, step, self.options))
                yield sample
