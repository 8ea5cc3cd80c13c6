"""Log formats: one registry and one factory through which every log is opened.

A format is a name (used alike on input: ``dsnet label --format``, ``describe``, ``serve``; and
on output: ``dsnet export --format``), a detection rule on the log's root, and a constructor
that returns a :class:`~dsnet_core.io.reader.LogReader`. ``format="auto"`` asks every registered
format's rule in registration order and takes the first that accepts the root; nothing
accepting is a :class:`UnknownLogFormatError` that lists what was found and the formats that
exist. Each format declares its reader options with the values they allow
(:mod:`dsnet_core.io.options`); :func:`open_log` checks them before the reader opens, so a bad value
is one line naming the option and what it takes. The run store records the resolved format and
the reader options, so every stage reads the log the same way.

Add a format by calling :func:`register` (the built-in ones are registered below, at the end).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from dsnet_core.errors import DataFormatError
from dsnet_core.io import options as opt
from dsnet_core.io.intensity import CONVENTIONS
from dsnet_core.io.options import ReaderOption, check_options
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
        options: the reader options ``open`` accepts (``dsnet label --reader-option KEY=VALUE``),
            each with the values it allows (a plain name allows any value).
    """

    name: str
    detect: Callable[[Path], bool]
    open: Callable[..., LogReader]
    description: str
    options: tuple[ReaderOption, ...] = ()

    def __post_init__(self) -> None:
        specs = tuple(o if isinstance(o, ReaderOption) else ReaderOption(str(o)) for o in self.options)
        object.__setattr__(self, "options", specs)


FORMATS: dict[str, LogFormat] = {}


def register(fmt: LogFormat) -> LogFormat:
    """Add (or replace) a format in the registry."""
    FORMATS[fmt.name] = fmt
    return fmt


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
        ConfigError: an option the format's reader does not take (the message lists its options),
            or a value the option does not allow (the message says what it allows).
        DataFormatError: the reader's own checks of the root.
    """
    name, parsed = check_reader_options(root, format, options)
    return FORMATS[name].open(Path(root).expanduser(), **parsed)


def check_reader_options(
    root: str | Path, format: str = "auto", options: dict[str, Any] | None = None
) -> tuple[str, dict[str, Any]]:
    """The log's format name and its parsed reader options, checked without opening the log (cheap:
    a command can refuse a bad option before it starts anything).

    Raises:
        UnknownLogFormatError: unknown name, or nothing detected.
        ConfigError: an option the format's reader does not take, or a value it does not allow.
    """
    name = detect_format(root) if format == "auto" else format
    if name not in FORMATS:
        raise UnknownLogFormatError(root, f"unknown format {name!r}; formats: {', '.join(FORMATS)}")
    return name, check_options(root, name, FORMATS[name].options, options)


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


SCAN_SUFFIXES = (".bin", ".npy", ".npz", ".pcd", ".ply", ".las", ".laz")
"""The folder reader's scan suffixes (``pointfiles.SUFFIXES``, which a test keeps equal: importing
it here would load numba with every import of this registry)."""
_CONVENTIONS = ("auto", *CONVENTIONS)
_INTENSITY = ReaderOption("intensity", f"one of {', '.join(_CONVENTIONS)}", opt.choice(*_CONVENTIONS))
_INTENSITY_FIELD = ReaderOption("intensity_field", "the name of a point field", opt.text)
_LABEL_MAP = ReaderOption("label_map", opt.label_map_allowed(), opt.label_map())

register(
    LogFormat(
        "semantickitti",
        _is_semantickitti,
        _open_semantickitti,
        "sequences/SS/velodyne/*.bin with optional labels/, poses.txt, calib.txt, times.txt",
        (_LABEL_MAP, ReaderOption("check_labels", "true or false", opt.boolean)),
    )
)
register(
    LogFormat(
        "nuscenes",
        _is_nuscenes,
        _open_nuscenes,
        "v1.0-*/ JSON tables with samples/ and sweeps/ LIDAR_TOP .pcd.bin, optional panoptic/ and lidarseg/",
        (
            ReaderOption("version", "the name of a v1.0-* table folder", opt.text),
            ReaderOption("sweeps", "true or false", opt.boolean),
            ReaderOption("channel", "a sensor channel (LIDAR_TOP)", opt.text),
            ReaderOption(
                "label_map", opt.label_map_allowed("panoptic-nuscenes"), opt.label_map("panoptic-nuscenes")
            ),
        ),
    )
)
register(
    LogFormat(
        "rosbag",
        _is_rosbag,
        _open_rosbag,
        "a ROS 2 bag (folder with metadata.yaml, or .mcap/.db3) or a folder of bags, PointCloud2 + /tf",
        (
            ReaderOption("topic", "a PointCloud2 topic name", opt.text),
            ReaderOption("fixed_frame", "a tf frame name", opt.text),
            _INTENSITY,
            _INTENSITY_FIELD,
            ReaderOption("tf_tolerance_s", "seconds, a number ≥ 0", opt.seconds),
            _LABEL_MAP,
        ),
    )
)
register(
    LogFormat(
        "folder",
        _is_folder,
        _open_folder,
        "a folder (or folders) of .bin/.npy/.npz/.pcd/.ply/.las/.laz scans, optional poses.txt/times.txt",
        (
            ReaderOption("order", "name or time", opt.choice("name", "time")),
            _INTENSITY,
            _INTENSITY_FIELD,
            ReaderOption(
                "bin_columns",
                "4 or 5 (float32 columns of the .bin scans: x y z intensity [ring])",
                opt.int_choice(4, 5),
            ),
            ReaderOption("suffix", f"one of {', '.join(SCAN_SUFFIXES)}", opt.suffix(SCAN_SUFFIXES)),
            _LABEL_MAP,
            ReaderOption("pose_tolerance_s", "seconds, a number ≥ 0", opt.seconds),
        ),
    )
)
