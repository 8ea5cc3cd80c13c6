"""The reader protocol: every log format (SemanticKITTI, nuScenes, folders of scans, ROS 2 bags,
the synthetic generator's output) is read through this small interface.

Every reader returns scans in the model's convention (float32 x, y, z in metres and 0–1
remission, through :func:`dsnet_core.io.intensity.normalise_intensity`) and states the source's
intensity convention per sequence (``intensity_convention``).

Readers hand out every finite point, however far: the model clamps points beyond its
cylindrical grid into the grid's edge cells (never drops them, so labels keep the scan's point
count and order), and ingest records per frame the source's intensity convention and how many
points lie outside the model's grid (``intensity_convention``, ``outside_grid`` in the frame
table; ``docs/algorithm.md``, "Cylindrical grid"). Points without a return (NaN x/y/z: organised
PCD clouds and PointCloud2 messages keep their grid shape that way) are dropped by the readers of
formats that have them, which then offer ``dropped_points(frame) -> int`` and
``kept_points(frame) -> bool (M,) | None`` (the mask over the source's M points; None when nothing
was dropped): ingest records the count (``no_return``) and exports write a label for every source
point, 0 (unlabelled) for the dropped ones. Optional methods ``sensor_fields(sequence)`` and
``pose_source(sequence)`` describe the source for ``dsnet describe``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Protocol, runtime_checkable

import numpy as np

from dsnet_core.labels import LabelMap


@dataclass(frozen=True)
class FrameRef:
    """One frame of a sequence.

    Attributes:
        sequence: sequence name (``"08"``).
        frame_id: frame name: the file stem (``"000042"``), a nuScenes sample_data token, a bag
            message's header stamp in ns; exports name their files by it.
        index: position of the frame in its sequence (0-based, in the log's order).
        scan_path: the scan file (for a bag: the bag).
        label_path: the label file, or None when the log has no labels for it.
    """

    sequence: str
    frame_id: str
    index: int
    scan_path: Path
    label_path: Path | None = None


@runtime_checkable
class LogReader(Protocol):
    """Read-only access to a driving log.

    Attributes:
        root: the log's root.
        format: the registered format name (:mod:`dsnet_core.io.formats`).
        label_map: the ground truth's label map (raw ids in ``labels``), or None for a log whose
            format has no labels.
    """

    root: Path
    format: str
    label_map: LabelMap | None

    def sequences(self) -> list[str]:
        """Sequence names, sorted."""
        ...

    def frames(self, sequence: str) -> list[FrameRef]:
        """The frames of a sequence in the log's order (name, or time where the format says)."""
        ...

    def scan(self, frame: FrameRef) -> np.ndarray:
        """float32 ``(N, 4)``: x, y, z (metres, sensor frame), remission in [0, 1]."""
        ...

    def intensity_convention(self, sequence: str) -> str:
        """The source's intensity convention (:data:`dsnet_core.io.intensity.CONVENTIONS`)."""
        ...

    def labels(self, frame: FrameRef) -> np.ndarray | None:
        """uint32 ``(N,)`` raw semantic | instance << 16, or None without labels."""
        ...

    def pose(self, frame: FrameRef) -> np.ndarray | None:
        """float64 ``(4, 4)`` LiDAR-frame pose (sensor → world), or None without poses."""
        ...

    def timestamp(self, frame: FrameRef) -> float | None:
        """Seconds, or None."""
        ...

    def poses(self, sequence: str) -> np.ndarray | None:
        """float64 ``(F, 4, 4)`` LiDAR-frame poses of every frame of a sequence, or None."""
        ...
