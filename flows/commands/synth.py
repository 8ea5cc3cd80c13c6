"""``dsnet synth`` and ``dsnet demo``: synthetic driving logs. Heavy imports stay in the bodies."""

from __future__ import annotations

from pathlib import Path

import typer


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
    from flows.cli import _fail

    names = _generate(out, sequences, frames, seed, sensor, first_sequence, overwrite, _fail)
    typer.echo(
        f"wrote {len(names)} sequence(s) × {frames} frames ({sensor}) to {out.resolve() / 'sequences'}"
    )


def demo(
    out: Path = typer.Option(Path("demo-out"), help="Where to write the demo log."),
    frames: int = typer.Option(10, min=1, help="Sweeps in the demo sequence."),
    seed: int = typer.Option(0, help="Seed of the synthetic log."),
) -> None:
    """Run the main job on the embedded default: today, generate a synthetic log and describe it."""
    from dsnet_core.describe import summarize
    from dsnet_core.io.semantickitti import SemanticKittiReader
    from flows.cli import _fail, _print_summary

    typer.echo(f"[1/2] generating a synthetic HDL-64 log: 1 sequence × {frames} frames, seed {seed}")
    _generate(out, 1, frames, seed, "hdl64", 0, True, _fail)
    typer.echo(f"      wrote {out.resolve() / 'sequences' / '00'}")
    typer.echo("[2/2] reading it back through the SemanticKITTI reader (every file checked)")
    _print_summary(summarize(SemanticKittiReader(out)))
    typer.echo(
        "Labelling: not yet available. This demo does not run a model or the labelling flow yet; "
        "it stops after generating and checking the input log."
    )


def _generate(out, sequences, frames, seed, sensor, first_sequence, overwrite, fail) -> list[str]:
    from rich.progress import Progress

    from dsnet_core.errors import DsnetError
    from dsnet_core.synth import generate_log

    try:
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
    except DsnetError as exc:
        fail(exc)
        raise  # unreachable: fail() exits
