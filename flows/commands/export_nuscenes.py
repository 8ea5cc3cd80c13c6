"""``dsnet export --format nuscenes``: a nuScenes log's labels as nuscenes-devkit results."""

from __future__ import annotations

from pathlib import Path

import typer

from flows.commands.common import errors_exit


def export_nuscenes_command(root: str, out: Path, sequences: list[str] | None, split: str) -> None:
    """Write ``OUT/{lidarseg,panoptic}/<split>/<sample_data token>_*`` and ``OUT/<split>/submission.json``."""
    from flows.export_nuscenes import export_nuscenes

    with errors_exit():
        result = export_nuscenes(root, out, sequences, split)
    for scene, tokens in result.tokens.items():
        line = f"scene {scene}: {len(tokens)} lidarseg and panoptic files"
        missing = result.missing[scene]
        if missing:
            line += f" ({len(missing)} sample_data without a label: {', '.join(missing[:3])})"
        typer.echo(line)
    typer.echo(f"class mapping {result.mapping['file']} (model classes -> nuScenes challenge classes)")
    typer.echo(
        f"wrote nuScenes results to {result.out.resolve()} (devkit: --result_path OUT --eval_set {split})"
    )
