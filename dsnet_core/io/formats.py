"""Log formats: one registry and one factory through which every log is opened.

A format is a name (used alike on input: ``dsnet label --format``, ``describe``, ``serve``; and
on output: ``dsnet export --format``), a detection rule on the log's root, and a constructor
that returns a :class:`~dsnet_core.io.reader.LogReader`. ``format="auto"`` asks every registered
format's rule in registration order and takes the first that accepts the root; nothing
accepting is a :class:`UnknownLogFormatError` that lists what was found and the formats that
exist. The run store records the resolved format and the reader options, so every stage reads
the log the same way.

Add a format by calling :func:`register` (the built-in ones are registered below, at the end).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from dsnet_core.errors import ConfigError, DataFormatError
from dsnet_core.io.reader import LogReader


class UnknownLogFormatError(DataFormatError):
    """No registered format accepts a log root, or an unknown format name was asked for."""


@dataclass(frozen=True)
class LogFormat:
    """One log format.

    Attributes:
        name: the format's name on the command line (``semantickitti``).
        detect: True when a root folder (or file) is in this format; cheap (names, not contents).
        open: ``open(root, **options) -> LogReader``.
        description: one line for error messages and ``--help``.
        options: the reader options ``open`` accepts (``dsnet label --reader-option KEY=VALUE``).
    """

    name: str
    detect: Callable[[Path], bool]
    open: Callable[..., LogReader]
    description: str
    options: tuple[str, ...] = ()


FORMATS: dict[str, LogFormat] = {}


def register(fmt: LogFormat) -> LogFormat:
    """Add (or replace) a format in the registry."""
    FORMATS[fmt.name] = fmt
    return fmt


def format_names() -> list[str]:
    return list(FORMATS)


def detect_format(root: str | Path) -> str:
    """The name of the first registered format that accepts ``root``.

    Raises:
        UnknownLogFormatError: nothing accepts it; the message lists what the root holds.
    """
    path = Path(root).expanduser()
    if not path.exists():
        raise UnknownLogFormatError(path, "no such file or folder")
    for fmt in FORMATS.values():
        if fmt.detect(path):
            return fmt.name
    raise UnknownLogFormatError(
        path,
        f"not a log format this tool reads (found {_listing(path)}); formats: "
        + "; ".join(f"{f.name} ({f.description})" for f in FORMATS.values()),
    )


def open_log(root: str | Path, format: str = "auto", options: dict[str, Any] | None = None) -> LogReader:
    """Open a log through its format's reader.

    Args:
        root: the log's root folder (or file, for single-file formats).
        format: a registered name, or ``"auto"`` to detect it.
        options: reader options (recorded in the run config by the caller).

    Raises:
        UnknownLogFormatError: unknown name, or nothing detected.
        ConfigError: an option the format's reader does not take (the message lists its options).
        DataFormatError: the reader's own checks of the root.
    """
    name = detect_format(root) if format == "auto" else format
    if name not in FORMATS:
        raise UnknownLogFormatError(root, f"unknown format {name!r}; formats: {', '.join(FORMATS)}")
    fmt = FORMATS[name]
    unknown = sorted(set(options or {}) - set(fmt.options))
    if unknown:
        raise ConfigError(
            f"{root}: the {name} reader has no option {', '.join(map(repr, unknown))}; its options are "
            f"{', '.join(fmt.options) or 'none'}"
        )
    return fmt.open(Path(root).expanduser(), **(options or {}))


def _listing(path: Path, limit: int = 8) -> str:
    if path.is_file():
        return f"a file with suffix {path.suffix or '(none)'}"
    names = sorted(p.name + ("/" if p.is_dir() else "") for p in path.iterdir())
    if not names:
        return "an empty folder"
    more = f" and {len(names) - limit} more" if len(names) > limit else ""
    return ", ".join(names[:limit]) + more


def _is_semantickitti(path: Path) -> bool:
    return path.is_dir() and (path / "sequences").is_dir()


def _open_semantickitti(root: Path, **options: Any) -> LogReader:
    from dsnet_core.io.semantickitti import SemanticKittiReader

    return SemanticKittiReader(root, **options)


def _is_nuscenes(path: Path) -> bool:
    from dsnet_core.io.nuscenes_reader import find_versions

    return bool(find_versions(path))


def _open_nuscenes(root: Path, **options: Any) -> LogReader:
    from dsnet_core.io.nuscenes_reader import NuScenesReader

    return NuScenesReader(root, **options)


def _is_rosbag(path: Path) -> bool:
    from dsnet_core.io.rosbag import is_bag

    return is_bag(path) or (path.is_dir() and any(is_bag(p) for p in path.iterdir()))


def _open_rosbag(root: Path, **options: Any) -> LogReader:
    from dsnet_core.io.rosbag import RosbagReader

    return RosbagReader(root, **options)


def _is_folder(path: Path) -> bool:
    from dsnet_core.io.folder import scan_files

    return bool(scan_files(path)) or (
        path.is_dir() and any(scan_files(p) for p in path.iterdir() if p.is_dir())
    )


def _open_folder(root: Path, **options: Any) -> LogReader:
    from dsnet_core.io.folder import FolderReader

    return FolderReader(root, **options)


register(
    LogFormat(
        "semantickitti",
        _is_semantickitti,
        _open_semantickitti,
        "sequences/SS/velodyne/*.bin with optional labels/, poses.txt, calib.txt, times.txt",
        ("label_map", "check_labels"),
    )
)
register(
    LogFormat(
        "nuscenes",
        _is_nuscenes,
        _open_nuscenes,
        "v1.0-*/ JSON tables with samples/ and sweeps/ LIDAR_TOP .pcd.bin, optional panoptic/ and lidarseg/",
        ("version", "sweeps", "channel", "label_map"),
    )
)
register(
    LogFormat(
        "rosbag",
        _is_rosbag,
        _open_rosbag,
        "a ROS 2 bag (folder with metadata.yaml, or .mcap/.db3) or a folder of bags, PointCloud2 + /tf",
        ("topic", "fixed_frame", "intensity", "intensity_field", "tf_tolerance_s", "label_map"),
    )
)
register(
    LogFormat(
        "folder",
        _is_folder,
        _open_folder,
        "a folder (or folders) of .bin/.npy/.npz/.pcd/.ply/.las/.laz scans, optional poses.txt/times.txt",
        ("order", "intensity", "intensity_field", "bin_columns", "suffix", "label_map", "pose_tolerance_s"),
    )
)
