"""Stage ``ingest``: read a log through the reader protocol and write the frame table.

Per frame: id, source path, point count, LiDAR-frame pose and where it came from, timestamp,
checksum (blake2b of the scan's and labels' bytes), status, the source's intensity convention
(the reader hands the model 0–1 remission whatever the source stored: :mod:`dsnet_core.io.intensity`),
the points the reader dropped as no returns (NaN coordinates of organised clouds; exports put them
back, unlabelled) and the points outside the model's cylindrical grid (the model clamps them into
the grid's edge cells, :mod:`dsnet_core.model.bounds`; counted in the scan's own sensor frame
against the grid the request records in ``grid``, from the model card). With ``on_error="skip"`` a
bad frame is quarantined with the reader's message and the rest proceeds; by default the reader's
error fails the sequence.

A log without poses gets them from KISS-ICP odometry when ``estimate_poses`` is set
(:mod:`dsnet_core.temporal.odometry`; LiDAR-frame poses, the first ok frame being the world, ``Tr`` =
identity). Odometry is sequential, so such a sequence is one block. A log's own poses always win.
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Iterator

import numpy as np
import pyarrow as pa
from pydantic import Field

from dsnet_core.errors import DataFormatError, ScanFormatError
from dsnet_core.model.bounds import outside_grid
from dsnet_core.temporal.odometry import Odometry, OdometryError
from storage.contract import TableSpec
from tasks.base import ItemResult, Plan, Stage, StageConfig, StageContext

FRAMES = TableSpec(
    "frames",
    pa.schema(
        [
            ("index", pa.int32()),
            ("frame_id", pa.string()),
            ("source_path", pa.string()),
            ("label_path", pa.string()),
            ("n_points", pa.int64()),
            ("pose", pa.list_(pa.float64(), 16)),  # LiDAR-frame 4×4 sensor→world, row-major
            ("pose_source", pa.string()),  # "log" | "estimated" (ingest --estimate-poses) | None
            ("timestamp", pa.float64()),
            ("checksum", pa.string()),  # blake2b of scan bytes + label bytes
            ("has_labels", pa.bool_()),
            ("status", pa.string()),  # "ok" | "quarantined"
            ("reason", pa.string()),
            ("intensity_convention", pa.string()),  # the source's: unit | uint8 | uint16 | none
            ("outside_grid", pa.int64()),  # points outside the model's grid (clamped); null: no grid
            ("no_return", pa.int64()),  # source points without a return (NaN), dropped by the reader
        ]
    ),
)


def frame_checksum(scan: np.ndarray, labels: np.ndarray | None) -> str:
    """blake2b-128 of the scan's float32 bytes followed by the labels' uint32 bytes."""
    h = hashlib.blake2b(np.ascontiguousarray(scan, np.float32).tobytes(), digest_size=16)
    if labels is not None:
        h.update(np.ascontiguousarray(labels, np.uint32).tobytes())
    return h.hexdigest()


def _stat(path) -> list:
    if path is None:
        return [None]
    try:
        st = os.stat(path)
    except OSError:
        return [str(path), None]
    return [os.path.basename(path), st.st_size, st.st_mtime_ns]


class GridBounds(StageConfig):
    """The bounds of a model's cylindrical grid: (ρ m, φ rad, z m) lower and upper."""

    min_bound: tuple[float, float, float]
    max_bound: tuple[float, float, float]


MAX_POINTS = 2_000_000
"""Default per-frame point limit: a 128-beam sensor gives ~0.3 M points per sweep."""


class IngestConfig(StageConfig):
    """Ingest settings (with the version and the source listing, they decide the fingerprint).

    Attributes:
        estimate_poses: estimate LiDAR poses by KISS-ICP odometry for sequences whose log has none
            (no effect where the log has poses).
        grid: the model's grid bounds, against which each scan's points outside the grid are
            counted (``flows.request.LabelRequest.stage_configs`` fills it from the model card);
            None leaves ``outside_grid`` null.
        max_points: the most points a frame may have: memory grows with a frame's points (about
            1.3 GB per million at k = 1 through the model stages), so a larger frame is refused (or
            quarantined with ``on_error="skip"``) before it reaches them.
    """

    estimate_poses: bool = False
    grid: GridBounds | None = None
    max_points: int = Field(MAX_POINTS, ge=1)


def _log_pose_source(reader, frames) -> str | None:
    """Where the sequence's poses come from: ``"log"``, or None when the log has none. Poses the
    reader cannot parse count as the log's: their error is reported per frame, never replaced."""
    if not frames:
        return None
    try:
        return None if reader.pose(frames[0]) is None else "log"
    except DataFormatError:
        return "log"


def _no_returns(reader, frame) -> int:
    """Points of the frame's source the reader dropped as no returns (0 for formats without any)."""
    dropped = getattr(reader, "dropped_points", None)  # optional: cached from the scan just read
    return 0 if dropped is None else int(dropped(frame))


class IngestStage(Stage):
    name = "ingest"
    upstream = ()
    version = "4"  # 2: pose_source, estimated poses; 3: intensity_convention, outside_grid; 4: no_return
    Config = IngestConfig
    item = "frame"
    tables = (FRAMES,)

    def inputs(self, ctx: StageContext) -> str:
        """The format and reader options the run opens the log with, the names, sizes and mtimes of
        every scan and label file, and the poses and times values."""
        reader = ctx.reader
        h = hashlib.blake2b(digest_size=16)
        h.update(repr((reader.format, sorted(ctx.run.reader_options.items()))).encode())
        frames = reader.frames(ctx.sequence)
        h.update(repr([(_stat(f.scan_path), _stat(f.label_path)) for f in frames]).encode())
        try:
            for frame in (frames[0], frames[-1]):  # force the (cached) parse of poses and times
                reader.pose(frame), reader.timestamp(frame)
            poses = [reader.pose(f) for f in frames]
            times = [reader.timestamp(f) for f in frames]
        except DataFormatError as exc:  # bad poses: the digest must still differ from a good log's
            h.update(str(exc).encode())
        else:
            h.update(np.asarray([p if p is not None else np.full((4, 4), np.nan) for p in poses]).tobytes())
            h.update(repr(times).encode())
        return h.hexdigest()

    def plan(self, ctx: StageContext) -> Plan:
        frames = ctx.reader.frames(ctx.sequence)
        n = len(frames)
        source = _log_pose_source(ctx.reader, frames)
        if source is None and ctx.config.estimate_poses and n:  # one block: odometry is sequential
            return Plan(n_items=n, meta={"pose_source": "estimated"}, blocks=[list(range(n))])
        return Plan(n_items=n, meta={"pose_source": source})

    def run_block(self, ctx: StageContext, items: list[int]) -> Iterator[ItemResult]:
        reader = ctx.reader
        frames = reader.frames(ctx.sequence)
        estimate = ctx.plan.get("pose_source") == "estimated"
        if estimate and list(items) != list(range(len(frames))):
            raise ValueError(f"pose estimation needs the whole sequence in one block, got items {items}")
        odometry = Odometry() if estimate else None
        grid = ctx.config.grid
        for i in items:
            frame = frames[i]
            row = {
                "index": i,
                "frame_id": frame.frame_id,
                "source_path": str(frame.scan_path),
                "label_path": None if frame.label_path is None else str(frame.label_path),
                "n_points": 0,
                "pose": None,
                "pose_source": None,
                "timestamp": None,
                "checksum": "",
                "has_labels": frame.label_path is not None,
                "status": "ok",
                "reason": None,
                "intensity_convention": None,
                "outside_grid": None,
                "no_return": None,
            }
            try:
                scan = reader.scan(frame)
                if scan.shape[0] > ctx.config.max_points:
                    raise ScanFormatError(
                        frame.scan_path,
                        f"{scan.shape[0]} points exceed the limit of {ctx.config.max_points} per frame "
                        "(memory grows by about 1.3 GB per million points): raise it with --max-points",
                    )
                labels = reader.labels(frame)
                pose = reader.pose(frame)
                row["timestamp"] = reader.timestamp(frame)
                row["intensity_convention"] = reader.intensity_convention(ctx.sequence)
                if odometry is not None:
                    pose = odometry.register(scan, str(frame.scan_path))
            except (DataFormatError, OdometryError) as exc:
                if ctx.run.options.on_error != "skip":
                    raise
                row.update(status="quarantined", reason=str(exc))
                yield ItemResult(i, rows={"frames": [row]}, counts={"frames": 1, "quarantined": 1})
                continue
            row.update(
                n_points=int(scan.shape[0]),
                pose=None if pose is None else [float(v) for v in np.asarray(pose).reshape(-1)],
                pose_source=None if pose is None else ("estimated" if estimate else "log"),
                checksum=frame_checksum(scan, labels),
                outside_grid=None
                if grid is None
                else int(outside_grid(scan, grid.min_bound, grid.max_bound).sum()),
                no_return=_no_returns(reader, frame),
            )
            counts = {"frames": 1, "points": int(scan.shape[0]), "quarantined": 0}
            if row["outside_grid"] is not None:
                counts["outside_grid"] = row["outside_grid"]
            yield ItemResult(i, rows={"frames": [row]}, counts=counts)
