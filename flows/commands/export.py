"""``dsnet export``: a run store's final labels as files other tools read, in the log's own terms."""

from __future__ import annotations

from pathlib import Path

import typer

from flows.commands.common import check_output, errors_exit


def export(
    root: str = typer.Argument(..., help="Run store root (folder or s3://…)."),
    out: Path = typer.Option(..., "--out", help="Output root."),
    format: str = typer.Option(
        None,
        "--format",
        help="semantickitti (.label files in sequences/SS/predictions/), folder (SEQ/<scan name>.label), "
        "rosbag (BAG/<stamp ns>.label) or nuscenes (lidarseg/ and panoptic/ results by sample_data token); "
        "default: the format of the run's log.",
    ),
    split: str = typer.Option(
        "val", "--split", help="nuscenes: the devkit's eval_set folder name (val, mini_val, test, ...)."
    ),
    sequences: str = typer.Option(None, help="Comma-separated sequences (default: every finished one)."),
) -> None:
    """Write the run's final labels in its log's format (or --format): one file per scan, named as
    the log names the scan (frame number, scan file name, message stamp or sample_data token)."""
    from flows.export_formats import EXPORTS, default_export_format, export

    seqs = sequences.split(",") if sequences else None
    with errors_exit():
        check_output(out, "--out", "folder")
        format = format or default_export_format(root)
    if format not in EXPORTS:
        raise typer.BadParameter(f"unknown format {format!r} (available: {', '.join(EXPORTS)})")
    with errors_exit():
        fmt, summary = export(root, out, format, seqs, split=split)
    for line in fmt.lines(summary):
        typer.echo(line)
