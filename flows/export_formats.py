"""Export formats: one registry through which ``dsnet export`` finds how to write a run's labels.

A format is a name (``--format``; an input format's name where they correspond), a writer
``write(root, out, sequences, options)``, the lines the command prints of what was written, and
the options the writer takes with their defaults. Add one with :func:`register_export`; the
built-in ones (:mod:`flows.export`, :mod:`flows.export_nuscenes`) are registered below.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from flows.export import ExportSummary, export_frames, export_semantickitti
from flows.export_nuscenes import export_nuscenes, nuscenes_lines
from storage.run import RunStore
from tasks.run_config import read_run


@dataclass(frozen=True)
class ExportFormat:
    """One output format of ``dsnet export``.

    Attributes:
        name: the ``--format`` name (an input format's name where they correspond).
        write: ``write(root, out, sequences, options) -> summary`` (``options``: this format's,
            defaults filled in).
        lines: ``lines(summary) -> list[str]``: what the command prints after writing.
        help: one line for ``--help`` and errors.
        options: the options the writer takes, with their defaults (``--split`` for nuscenes).
    """

    name: str
    write: Callable[..., Any]
    lines: Callable[[Any], list[str]]
    help: str
    options: dict[str, Any] = field(default_factory=dict)


EXPORTS: dict[str, ExportFormat] = {}


def register_export(fmt: ExportFormat) -> ExportFormat:
    """Add (or replace) an export format."""
    EXPORTS[fmt.name] = fmt
    return fmt


def export(
    root: str, out: str | Path, format: str, sequences: list[str] | None = None, **options: Any
) -> tuple[ExportFormat, Any]:
    """Export through the registered ``format`` (options it does not take are dropped).

    Raises:
        ValueError: an unknown format (the message lists the registered ones).
    """
    if format not in EXPORTS:
        raise ValueError(f"unknown format {format!r} (available: {', '.join(EXPORTS)})")
    fmt = EXPORTS[format]
    opts = {k: options[k] if options.get(k) is not None else v for k, v in fmt.options.items()}
    return fmt, fmt.write(root, out, sequences, opts)


def summary_lines(summary: ExportSummary, where: Path, name: str) -> list[str]:
    """Per sequence the files written (and those missing or swept), then where."""
    out = []
    for seq, n in summary.frames.items():
        line = f"sequence {seq}: {n} label files"
        missing = summary.missing[seq]
        if missing:
            line += f" ({len(missing)} frames without a label: {', '.join(missing[:5])})"
        removed = summary.removed.get(seq)
        if removed:
            line += (
                f"; removed {len(removed)} .label files an earlier export left for frames this export does "
                f"not write: {', '.join(removed[:5])}{', …' if len(removed) > 5 else ''}"
            )
        out.append(line)
    out.append(f"wrote {name} labels to {where}")
    return out


def _nuscenes(root: str, out: str | Path, sequences: list[str] | None, options: dict[str, Any]):
    return export_nuscenes(root, out, sequences, options["split"])


register_export(
    ExportFormat(
        "semantickitti",
        lambda root, out, seqs, _: export_semantickitti(root, out, seqs),
        lambda s: summary_lines(s, s.out.resolve() / "sequences", "semantickitti"),
        ".label files in sequences/SS/predictions/",
    )
)
register_export(
    ExportFormat(
        "nuscenes",
        _nuscenes,
        nuscenes_lines,
        "lidarseg/ and panoptic/ results by sample_data token (a run of a nuScenes log)",
        {"split": "val"},
    )
)
for _name, _help in (("folder", "SEQ/<scan name>.label"), ("rosbag", "BAG/<stamp ns>.label")):
    register_export(
        ExportFormat(
            _name,
            lambda root, out, seqs, _: export_frames(root, out, seqs),
            lambda s, _name=_name: summary_lines(s, s.out.resolve(), _name),
            _help,
        )
    )


def default_export_format(root: str, storage_options: dict | None = None) -> str:
    """The format a run exports in by default: its log's (``semantickitti`` for a run of an
    unregistered format, or one recorded before formats existed)."""
    fmt = read_run(RunStore(root, storage_options)).format
    return fmt if fmt in EXPORTS else "semantickitti"
