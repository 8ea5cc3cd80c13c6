"""``dsnet export --format nuscenes``: Panoptic nuScenes ``.npz`` files of a run store."""

from __future__ import annotations

from pathlib import Path

import typer

from flows.commands.common import errors_exit


def export_nuscenes_command(root: str, out: Path, sequences: str | None) -> None:
    """Write ``OUT/panoptic/v1.0-trainval/<sequence>-<frame>_panoptic.npz`` and ``OUT/tokens.json``."""
    from flows.export_nuscenes import export_nuscenes

    with errors_exit():
        result = export_nuscenes(root, out, sequences.split(",") if sequences else None)
    for seq, tokens in result.tokens.items():
        typer.echo(f"scene {seq}: {len(tokens)} panoptic files")
    typer.echo(f"wrote {result.folder.resolve()}")
