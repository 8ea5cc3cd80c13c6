"""``dsnet import-checkpoint``: a released DS-Net / 4D-DS-Net / Cylinder3D file → a checkpoint
folder that ``dsnet label --checkpoint`` runs (conversion: :mod:`dsnet_core.model.importer`)."""

from __future__ import annotations

from pathlib import Path

import typer

from flows.commands.common import errors_exit
from flows.commands.model_folder import check_import_target, writing_folder


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
        with writing_folder(out, "dsnet import-checkpoint"):
            replaced = check_import_target(out)
            card = run_import(src, out, kind, layout=layout, rulebooks=rulebooks)
    for line in summary_lines(out, card.architecture, card.training_data["imported"]):
        typer.echo(line)
    if replaced:
        typer.echo(replaced)


_LAYOUTS = {"spconv1": "spconv 1.x (*kernel, in, out)", "spconv2": "spconv 2.x (out, *kernel, in)"}


def summary_lines(out: Path, architecture: dict, imp: dict) -> list[str]:
    """What the import took and dropped, one fact a line: kind, width, layout, grid, dropped buffers."""
    conv, dropped, taps = imp["converted"], imp["dropped"], len(imp["dropped"]["kernel_taps"])
    epoch = f", epoch {imp['reference_epoch']}" if imp["reference_epoch"] is not None else ""
    buffers = ", ".join(f"{b['key']} {tuple(b['shape'])} ({b['about']})" for b in dropped["training_buffers"])
    lines = [
        f"wrote checkpoint {out.resolve()}",
        f"  source: {imp['source_file']} (sha256 {imp['source_sha256'][:12]}{epoch})",
        f"  kind: {imp['kind']}{' (semantics only)' if imp['semantic_only'] else ''}",
        f"  width: {architecture['width']} ({architecture['num_classes']} classes)",
        f"  layout: {_LAYOUTS[imp['sparse_layout']]}, {imp['rulebooks']} rulebooks",
        f"  grid convention: {imp['grid_convention']}",
        f"  converted: {conv['sparse_convolutions']} sparse convolutions, {conv['batch_norms']} batch norms, "
        f"{conv['linear_layers']} linear layers, {conv['shifting_iterations']} shifting iterations",
        f"  dropped buffers: {buffers or 'none'}",
    ]
    if taps:
        lines.append(f"  dropped kernel taps: {taps} weights beyond their shared rulebook's taps")
    if imp["semantic_only"]:
        lines.append(f"semantics only: train the instance head with dsnet train dsnet DATA --init-from {out}")
    return lines
