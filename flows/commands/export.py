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
    from flows.export import EXPORT_FORMATS, default_export_format, export_frames, export_semantickitti

    seqs = sequences.split(",") if sequences else None
    with errors_exit():
        check_output(out, "--out", "folder")
        format = format or default_export_format(root)
    if format not in EXPORT_FORMATS:
        raise typer.BadParameter(f"unknown format {format!r} (available: {', '.join(EXPORT_FORMATS)})")
    if format == "nuscenes":
        from flows.commands.export_nuscenes import export_nuscenes_command

        return export_nuscenes_command(root, out, seqs, split)
    with errors_exit():
        if format == "semantickitti":
            summary = export_semantickitti(root, out, seqs)
            where = out.resolve() / "sequences"
        else:
            summary = export_frames(root, out, seqs)
            where = out.resolve()
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
        typer.echo(line)
    typer.echo(f"wrote {format} labels to {where}")
