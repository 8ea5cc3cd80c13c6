"""``dsnet synth``: synthetic driving logs. Heavy imports stay in the bodies."""

from __future__ import annotations

from pathlib import Path

import typer

from flows.commands.common import errors_exit


def synth(
    out: Path = typer.Argument(..., help="Log root to write (gets sequences/SS/...)."),
    sequences: int = typer.Option(1, min=1, max=99, help="Number of sequences."),
    frames: int = typer.Option(20, min=1, help="Sweeps per sequence (10 Hz)."),
    seed: int = typer.Option(0, min=0, help="Master seed; each sequence derives its own from it."),
    sensor: str = typer.Option("hdl64", help="LiDAR model: hdl64 (64 beams) or vlp32 (32 beams, faster)."),
    first_sequence: int = typer.Option(0, min=0, max=99, help="Number of the first sequence."),
    overwrite: bool = typer.Option(False, help="Replace sequences that already exist."),
) -> None:
    """Ray-cast a procedural street with a spinning LiDAR and write it in the SemanticKITTI layout."""
    with errors_exit():
        generate(out, sequences, frames, seed, sensor, first_sequence, overwrite)
    typer.echo(f"wrote {sequences} sequence(s) × {frames} frames ({sensor}) to {out.resolve() / 'sequences'}")


def generate(
    out: Path,
    sequences: int = 1,
    frames: int = 20,
    seed: int = 0,
    sensor: str = "hdl64",
    first_sequence: int = 0,
    overwrite: bool = False,
) -> list[str]:
    """Write a synthetic log with a progress bar; returns the sequence names.

    Raises:
        DsnetError: bad settings, or sequences that exist without ``overwrite``.
    """
    from rich.progress import Progress

    from dsnet_core.synth import generate_log

    with Progress(transient=True) as progress:
        task = progress.add_task("ray-casting sweeps", total=sequences * frames)
        return generate_log(
            out,
            sequences=sequences,
            frames=frames,
            seed=seed,
            sensor=sensor,
            first_sequence=first_sequence,
            overwrite=overwrite,
            on_frame=lambda _seq, _i: progress.advance(task),
        )
