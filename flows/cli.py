"""The ``dsnet`` command line. Heavy imports live inside the commands so ``--help`` is instant."""

from __future__ import annotations

from pathlib import Path

import typer

app = typer.Typer(
    name="dsnet",
    help="Resumable 3D/4D LiDAR panoptic auto-labelling (DS-Net, 4D-DS-Net) and benchmark scoring.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


def _fail(exc: Exception) -> None:
    typer.secho(f"error: {exc}", fg=typer.colors.RED, err=True)
    raise typer.Exit(code=2)


@app.command()
def describe(
    data: Path = typer.Argument(..., help="Log root (any format `dsnet label` reads)."),
    sequences: str = typer.Option(None, help="Comma-separated sequence names (default: all)."),
    format: str = typer.Option("auto", "--format", help="Log format (default: detected)."),
) -> None:
    """Check every file of a log and print frames, points and the class histogram."""
    from dsnet_core.errors import DsnetError
    from dsnet_core.io.describe import summarize
    from dsnet_core.io.formats import open_log

    try:
        reader = open_log(data, format)
        seqs = sequences.split(",") if sequences else None
        summary = summarize(reader, seqs)
    except DsnetError as exc:
        _fail(exc)
        return
    _print_summary(summary)


def _print_summary(summary) -> None:
    from rich.console import Console
    from rich.table import Table

    console = Console()
    table = Table(title="sequences")
    for col in ("sequence", "frames", "points", "points/frame", "poses"):
        table.add_column(col, justify="right")
    for seq, n in summary.frames.items():
        pts = summary.points[seq]
        table.add_row(
            seq, str(n), str(pts), f"{pts / max(n, 1):.0f}", "yes" if summary.has_poses[seq] else "no"
        )
    console.print(table)
    if summary.class_points:
        total = sum(summary.class_points.values())
        hist = Table(title="class histogram (train ids)")
        for col in ("class", "points", "share", "instances"):
            hist.add_column(col, justify="right")
        for name, pts in summary.class_points.items():
            inst = summary.class_instances.get(name)
            hist.add_row(
                name, str(pts), f"{100 * pts / max(total, 1):.2f}%", "" if inst is None else str(inst)
            )
        console.print(hist)


# Command registrations: one line per command, bodies live in flows/commands/.
from flows.commands import demo as _demo  # noqa: E402
from flows.commands import export as _export  # noqa: E402
from flows.commands import label as _label  # noqa: E402
from flows.commands import synth as _synth  # noqa: E402
from flows.commands.dashboard import dashboard as _dashboard  # noqa: E402
from flows.commands.eval import eval_command  # noqa: E402
from flows.commands.serve import serve as _serve  # noqa: E402
from flows.commands.train import train as _train  # noqa: E402

app.command()(_synth.synth)
app.command()(_demo.demo)
app.command(name="eval")(eval_command)
app.command("label")(_label.label)
app.command("status")(_label.status)
app.command(name="train")(_train)
app.command("export")(_export.export)
app.command("dashboard")(_dashboard)
app.command("serve")(_serve)


def main() -> None:
    app()


if __name__ == "__main__":
    main()
