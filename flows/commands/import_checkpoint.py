"""``dsnet import-checkpoint``: a released DS-Net / 4D-DS-Net / Cylinder3D file → a checkpoint
folder that ``dsnet label --checkpoint`` runs (conversion: :mod:`dsnet_core.model.importer`)."""

from __future__ import annotations

from pathlib import Path

import typer

from flows.commands.common import errors_exit


def import_checkpoint(
    src: Path = typer.Argument(..., help="The released file (*.pth / *.pt)."),
    out: Path = typer.Option(..., "--out", help="Checkpoint folder to write."),
    kind: str = typer.Option(..., "--kind", help="dsnet | dsnet4d | cylinder3d (semantic only)."),
    layout: str = typer.Option("auto", help="Sparse weights' layout: auto | spconv1 | spconv2."),
    rulebooks: str = typer.Option(
        "auto", help="auto (spconv 1.x file: spconv1-shared; 2.x: per-layer) | spconv1-shared | per-layer."
    ),
) -> None:
    """Import a released reference checkpoint (read with weights_only=True, never unpickled)."""
    from dsnet_core.model.importer import import_checkpoint as run_import

    with errors_exit():
        card = run_import(src, out, kind, layout=layout, rulebooks=rulebooks)
    imp = card.training_data["imported"]
    conv = imp["converted"]
    typer.echo(
        f"wrote checkpoint {out.resolve()}: {imp['kind']} from {imp['source_file']} "
        f"(sha256 {imp['source_sha256'][:12]}), {conv['sparse_convolutions']} sparse convolutions "
        f"({imp['sparse_layout']} layout, {imp['rulebooks']} rulebooks), {conv['batch_norms']} batch "
        f"norms, {conv['linear_layers']} linear layers, {conv['shifting_iterations']} shifting "
        f"iterations; grid convention {imp['grid_convention']}"
    )
    if imp["semantic_only"]:
        typer.echo(f"semantics only: train the instance head with dsnet train dsnet DATA --init-from {out}")
