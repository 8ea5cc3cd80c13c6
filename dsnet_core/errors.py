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


class PoseFormatError(DataFormatError):
    """``poses.txt``/``calib.txt``/``times.txt`` is missing, short, or not rigid."""


class SequenceLayoutError(DataFormatError):
    """A sequence folder is empty, missing, or a path escapes the dataset root."""


class CheckpointError(DataFormatError):
    """A checkpoint is missing, unreadable or tampered with."""


class CheckpointMismatchError(CheckpointError):
    """A checkpoint's architecture or class map differs from what the caller expects."""


class ConfigError(DsnetError):
    """A configuration file or value is invalid."""
