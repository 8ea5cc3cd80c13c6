"""``dsnet export``: a run store's final labels as files other tools read."""

from __future__ import annotations

from pathlib import Path

import typer

from flows.commands.common import errors_exit


def export(
    root: str = typer.Argument(..., help="Run store root (folder or s3://…)."),
    out: Path = typer.Option(..., "--out", help="Output root (gets sequences/SS/predictions/)."),
    format: str = typer.Option("semantickitti", "--format", help="semantickitti or nuscenes."),
    sequences: str = typer.Option(None, help="Comma-separated sequences (default: every finished one)."),
) -> None:
    """Write the stitched labels as SemanticKITTI ``predictions/*.label`` (scorable by ``dsnet eval``)."""
    if format == "nuscenes":  # Panoptic nuScenes .npz, general classes (flows/export_nuscenes.py)
        from flows.commands.export_nuscenes import export_nuscenes_command

        return export_nuscenes_command(root, out, sequences)
    if format != "semantickitti":
        raise typer.BadParameter(f"unknown format {format!r} (available: semantickitti, nuscenes)")
    from flows.export import export_semantickitti

    with errors_exit():
        summary = export_semantickitti(root, out, sequences.split(",") if sequences else None)
    for seq, n in summary.frames.items():
        line = f"sequence {seq}: {n} label files"
        missing = summary.missing[seq]
        if missing:
            line += f" ({len(missing)} frames without a label: {', '.join(missing[:5])})"
        typer.echo(line)
    typer.echo(f"wrote {out.resolve() / 'sequences'}")
