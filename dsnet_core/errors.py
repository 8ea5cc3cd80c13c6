"""Typed exceptions. Every data error names the offending file and the problem."""

from __future__ import annotations

from pathlib import Path


class DsnetError(Exception):
    """Base class of every error this project raises on purpose."""


class DataFormatError(DsnetError):
    """A file of a driving log is malformed. ``path`` names it, ``problem`` says what is wrong."""

    def __init__(self, path: str | Path, problem: str) -> None:
        self.path = str(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")


class ScanFormatError(DataFormatError):
    """A scan (``.bin``) is truncated or holds non-finite values."""


class LabelFormatError(DataFormatError):
    """A label file does not match its scan, or holds ids the label map does not know."""


class PriorFormatError(DataFormatError):
    """A semantic prior file (D-PLS) is missing, does not match its scan's point count, holds class
    ids its label map does not know, or probabilities of the wrong width."""


class PoseFormatError(DataFormatError):
    """``poses.txt``/``calib.txt``/``times.txt`` is missing, short, or not rigid."""


class SequenceLayoutError(DataFormatError):
    """A sequence folder is empty, missing, or a path escapes the dataset root."""


class IntensityFormatError(ScanFormatError):
    """A scan's intensity column has a type or range its stated convention cannot hold."""


class PointFileFormatError(ScanFormatError):
    """A point-cloud file (PCD, PLY, LAS, NPY/NPZ, bin) is malformed: truncated body, unknown
    encoding, or no x/y/z."""


class TableFormatError(DataFormatError):
    """A log's index tables (nuScenes JSON tables) are malformed or point at missing files."""


class BagFormatError(DataFormatError):
    """A ROS bag cannot be read as a log: no or several PointCloud2 topics, unreadable messages."""


class CheckpointError(DataFormatError):
    """A checkpoint is missing, unreadable or tampered with."""


class CheckpointMismatchError(CheckpointError):
    """A checkpoint's architecture or class map differs from what the caller expects."""


class ConfigError(DsnetError):
    """A configuration file or value is invalid."""


class OutputPathError(ConfigError):
    """An output path names a file where a folder is written, a folder where a file is, or lies
    under a file. ``path`` names it, ``problem`` says what is wrong."""

    def __init__(self, path: str | Path, problem: str) -> None:
        self.path = str(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")


class ServiceError(DsnetError):
    """A service the run needs (the Prefect API, a Dask scheduler) does not answer, or is not that
    service. The message names its address and what to check."""


class MissingExtraError(DsnetError):
    """An optional dependency is not installed; the message names the ``pip install`` to run."""

    def __init__(self, module: str, extra: str, what: str) -> None:
        super().__init__(f"{what} needs the Python package {module!r}: pip install 'dsnet-pipeline[{extra}]'")


class CheckpointImportError(CheckpointError):
    """A reference checkpoint cannot be imported: unsafe pickle, unknown/missing/mis-shaped keys,
    or a sparse-weight layout that cannot be told apart."""
