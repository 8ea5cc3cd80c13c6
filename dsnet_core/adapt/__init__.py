"""Self-training on unlabelled target logs (pure numpy/torch; ``docs/adapt.md``).

- :mod:`~dsnet_core.adapt.selection`: class-balanced pseudo-label selection (per-class quantiles);
- :mod:`~dsnet_core.adapt.consistency`: voxel and track consistency of refined labels;
- :mod:`~dsnet_core.adapt.stats`: coverage, thresholds, precision per class for the card;
- :mod:`~dsnet_core.adapt.mixing`: LaserMix-style bands and PolarMix-style sectors;
- :mod:`~dsnet_core.adapt.ema`: the mean teacher;
- :mod:`~dsnet_core.adapt.trainer`: :class:`AdaptTrainer` on the trainer skeleton.
"""

from dsnet_core.adapt.config import MIN_HELDOUT, AdaptConfig, Labeller, RoundData
from dsnet_core.adapt.consistency import TrackVotes, VoxelVotes, frame_consistency, to_world
from dsnet_core.adapt.data import (
    Item,
    LabelOverlay,
    label_file,
    load_cloud,
    read_labels,
    volumes,
    write_labels,
)
from dsnet_core.adapt.ema import ema_update
from dsnet_core.adapt.mixing import MIX_MODES, Cloud, laser_mix, mix_pair, polar_mix
from dsnet_core.adapt.selection import ConfidenceHistogram, SelectionParams, select_frame
from dsnet_core.adapt.source import LogSource, StreamSource, stream_probe
from dsnet_core.adapt.stats import SelectionStats

__all__ = [
    "MIN_HELDOUT",
    "MIX_MODES",
    "AdaptConfig",
    "Cloud",
    "ConfidenceHistogram",
    "Item",
    "LabelOverlay",
    "Labeller",
    "LogSource",
    "RoundData",
    "SelectionParams",
    "SelectionStats",
    "StreamSource",
    "TrackVotes",
    "VoxelVotes",
    "ema_update",
    "frame_consistency",
    "label_file",
    "laser_mix",
    "load_cloud",
    "mix_pair",
    "polar_mix",
    "read_labels",
    "select_frame",
    "stream_probe",
    "to_world",
    "volumes",
    "write_labels",
]
