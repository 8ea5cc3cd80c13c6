"""Real labelled scans in training (``dsnet train dsnet … --real DIR --real-sequences S``).

A share of an epoch's samples (``share``) is a real scan (or a k-scan volume from its poses) of the
given sequences of a labelled log, mixed with that step's synthetic sample: LaserMix-style
inclination bands or PolarMix-style azimuth sectors (:mod:`dsnet_core.adapt.mixing`), or the real
scan alone (``mix = "none"``). The rest stay synthetic; the synthetic samples and their
augmentation are exactly those of a run without ``--real`` (the real draws have their own random
stream, a function of (seed, stage, epoch)).

What gives no loss: a point's semantic loss is masked where its train id is 0 — the label map
sends a real log's unlabelled (raw 0) and classes without a counterpart (SemanticKITTI's
``other-object``, raw 99, which is where PandaSet puts poles, fences, walls, cones…) to 0, which
:func:`~dsnet_core.model.losses.semantic_loss` ignores; a voxel takes the majority of its labelled
points only. Offset targets exist only for thing points with an instance id (thing points of a real
log in no cuboid have instance 0: no offset loss). Classes the real log lacks are taught by the
synthetic samples alone.

Instance centres are taken on each whole scan before mixing (an instance cut by a band keeps its
true centre), so a mixed :class:`~dsnet_core.train.data.Sample` carries its ``centre``.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dsnet_core.adapt.mixing import MIX_MODES, laser_masks, sector_mask
from dsnet_core.errors import ConfigError
from dsnet_core.io.reader import FrameRef, LogReader
from dsnet_core.labels import LabelMap
from dsnet_core.train.data import Sample, augment, class_counts, load_sample, volume_refs

REAL_STREAM = 7919
"""Key of the real draws' random stream beside (seed, stage, epoch)."""
REAL_INSTANCE_BIT = 1 << 38
"""Set in a real scan's instance keys so they never equal a synthetic scan's in a mixed sample."""
BANDS = (2, 6)
SECTOR_DEG = (45.0, 180.0)


@dataclass(frozen=True)
class RealOptions:
    """What ``--real`` trains on.

    Attributes:
        root: the labelled log's root.
        sequences: the sequences trained on (named explicitly; nothing defaults to every sequence).
        share: fraction of an epoch's samples that carry a real scan (0 < share ≤ 1).
        mix: ``both`` (laser or polar per sample), ``laser``, ``polar`` or ``none`` (the real scan
            alone).
        attribution: the data's attribution text, recorded in the card (e.g. "PandaSet by Hesai and
            Scale AI, CC BY 4.0").
    """

    root: Path
    sequences: tuple[str, ...]
    share: float = 0.5
    mix: str = "both"
    attribution: str | None = None

    def __post_init__(self) -> None:
        if not 0.0 < self.share <= 1.0:
            raise ConfigError(f"--real-share must be in (0, 1], got {self.share}")
        if self.mix not in MIX_MODES:
            raise ConfigError(f"unknown --real-mix {self.mix!r}; choose one of {', '.join(MIX_MODES)}")
        if not self.sequences:
            raise ConfigError(f"--real {self.root}: name the sequences to train on (--real-sequences)")


class RealData:
    """The real volumes of :class:`RealOptions` and how a sample takes one.

    Args:
        reader: the real log (its label map must be the training one's class set).
        options: what to train on.
        scans: scans per volume (k > 1 aligns the earlier scans by the log's poses).
        label_map: the training label map.

    Raises:
        ConfigError: an unknown or unlabelled sequence, a label map of another class count, or a
            k > 1 volume without poses.
    """

    def __init__(self, reader: LogReader, options: RealOptions, scans: int, label_map: LabelMap) -> None:
        self.reader, self.options, self.label_map = reader, options, label_map
        if reader.label_map is None:
            raise ConfigError(f"--real {options.root}: the log has no ground-truth labels")
        if reader.label_map.num_classes != label_map.num_classes:
            raise ConfigError(
                f"--real {options.root}: its label map has {reader.label_map.num_classes} classes, the "
                f"training data's {label_map.num_classes}"
            )
        known = reader.sequences()
        missing = [s for s in options.sequences if s not in known]
        if missing:
            raise ConfigError(
                f"--real {options.root}: no sequence {', '.join(missing)} (it has {', '.join(known)})"
            )
        self.volumes: list[list[FrameRef]] = []
        for seq in options.sequences:
            vols = volume_refs(reader, [seq], scans)
            if not vols:
                raise ConfigError(f"--real {options.root}: sequence {seq} has no labelled frames")
            if scans > 1 and reader.pose(vols[0][-1]) is None:
                raise ConfigError(
                    f"--real {options.root}: sequence {seq} has no poses for {scans}-scan volumes"
                )
            self.volumes.extend(vols)

    def files(self) -> list[Path]:
        """Every scan and label file the volumes read, sorted."""
        return sorted(
            {p for v in self.volumes for r in v for p in (r.scan_path, r.label_path) if p is not None}
        )

    def record(self) -> dict:
        """What the card records: the log, sequences, frames, the sha256 over every file read (its
        path relative to the log and its whole content), class counts, share, mix, attribution."""
        h = hashlib.sha256()
        root = Path(self.reader.root)
        files = self.files()
        for p in files:
            h.update(str(Path(p).relative_to(root)).encode() + b"\0")
            h.update(Path(p).read_bytes())
        o = self.options
        return {
            "root": str(root.resolve()),
            "format": getattr(self.reader, "format", type(self.reader).__name__),
            "sequences": list(o.sequences),
            "frames": len(self.volumes),
            "frame_names": [f"{v[-1].sequence}/{v[-1].frame_id}" for v in self.volumes],
            "files": len(files),
            "sha256": h.hexdigest(),
            "class_points": class_counts(self.reader, self.volumes, self.label_map).tolist(),
            "share": o.share,
            "mix": o.mix,
            "attribution": o.attribution,
        }

    def load(self, index: int, rng: np.random.Generator | None) -> Sample:
        """Real volume ``index`` (augmented with ``rng`` when given), its instance keys marked real."""
        s = load_sample(self.reader, self.volumes[index], self.label_map)
        points = augment(s.points, rng) if rng is not None else s.points
        inst = np.where(s.inst > 0, s.inst | REAL_INSTANCE_BIT, 0)
        return Sample(points, s.sem, inst, s.thing, s.frame_index, s.name)

    def draw(
        self, synth: Sample, rng: np.random.Generator, augment_rng: np.random.Generator | None
    ) -> Sample:
        """One step's sample: ``synth`` (probability 1 − share) or a real volume mixed with it."""
        if rng.random() >= self.options.share:
            return synth
        real = self.load(int(rng.integers(len(self.volumes))), augment_rng)
        return mix_samples(real, synth, self.options.mix, rng)


def centres_of(sample: Sample) -> np.ndarray:
    """``(N, 3) float32``: each thing point's instance centre (middle of its tight box over the
    sample's points, as :func:`~dsnet_core.model.losses.instance_centres`), 0 elsewhere."""
    out = np.zeros((len(sample.sem), 3), np.float32)
    if not sample.thing.any():
        return out
    idx = np.flatnonzero(sample.thing)
    keys, inv = np.unique(sample.inst[idx], return_inverse=True)
    xyz = sample.points[idx, :3]
    lo = np.full((len(keys), 3), np.inf, np.float32)
    hi = np.full((len(keys), 3), -np.inf, np.float32)
    np.minimum.at(lo, inv, xyz)
    np.maximum.at(hi, inv, xyz)
    out[idx] = ((lo + hi) / 2)[inv]
    return out


def mix_samples(a: Sample, b: Sample, mode: str, rng: np.random.Generator) -> Sample:
    """A mix of ``a`` (the real one) and ``b``: ``a``'s points in the even inclination bands with
    ``b``'s in the odd ones (laser), or ``b`` with ``a``'s points in an azimuth sector (polar), or
    ``a`` alone (none); ``both`` draws laser or polar. Every point keeps its own label, instance,
    thing flag, frame index and centre (taken on its whole scan before mixing).

    Raises:
        ConfigError: an unknown mode.
    """
    if mode not in MIX_MODES:
        raise ConfigError(f"unknown mixing {mode!r}; choose one of {', '.join(MIX_MODES)}")
    ca = a.centre if a.centre is not None else centres_of(a)
    if mode == "none":
        return Sample(a.points, a.sem, a.inst, a.thing, a.frame_index, a.name, ca)
    if mode == "both":
        mode = ("laser", "polar")[int(rng.integers(2))]
    cb = b.centre if b.centre is not None else centres_of(b)
    if mode == "laser":
        keep_a, keep_b = laser_masks(a.points, b.points, int(rng.integers(BANDS[0], BANDS[1] + 1)))
        keep_b = ~keep_b
    else:
        start = float(rng.uniform(0.0, 2 * math.pi))
        width = math.radians(float(rng.uniform(*SECTOR_DEG)))
        keep_b = ~sector_mask(b.points, start, width)
        keep_a = sector_mask(a.points, start, width)

    def both(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return np.concatenate([x[keep_a], y[keep_b]])

    return Sample(
        points=both(a.points, b.points),
        sem=both(a.sem, b.sem),
        inst=both(a.inst, b.inst),
        thing=both(a.thing, b.thing),
        frame_index=both(a.frame_index, b.frame_index),
        name=f"{a.name}+{b.name}:{mode}",
        centre=both(ca, cb),
    )


def same_real(recorded: dict | None, now: dict | None) -> str | None:
    """Why a resumed run's ``--real`` differs from the one its checkpoint trained with (None: the
    same log content, sequences, share and mix)."""
    if recorded is None and now is None:
        return None
    if recorded is None:
        return "the checkpoint was trained without --real"
    if now is None:
        return f"the checkpoint was trained with --real {recorded['root']}"
    for key in ("sequences", "sha256", "share", "mix", "frames"):
        if recorded.get(key) != now.get(key):
            return f"its --real {key} was {recorded.get(key)!r}, now {now.get(key)!r}"
    return None
