"""``dsnet describe``: check every file of a log and print its size and class histogram."""

from __future__ import annotations

from pathlib import Path

import typer

from flows.commands.common import FIXED_FRAME_HELP, FORMAT_HELP, READER_OPTION_HELP, TOPIC_HELP, errors_exit


def describe(
    data: Path = typer.Argument(..., help="Log root (any format `dsnet label` reads)."),
    sequences: str = typer.Option(None, help="Comma-separated sequence names (default: all)."),
    format: str = typer.Option("auto", "--format", help=FORMAT_HELP),
    reader_option: list[str] = typer.Option(None, "--reader-option", help=READER_OPTION_HELP),
    topic: str = typer.Option(None, "--topic", help=TOPIC_HELP),
    fixed_frame: str = typer.Option(None, "--fixed-frame", help=FIXED_FRAME_HELP),
) -> None:
    """Check every file of a log and print its format, per sequence the frames, points per frame,
    sensor fields, intensity convention and pose source, and the class histogram."""
    from dsnet_core.io.describe import summarize
    from dsnet_core.io.formats import open_log
    from flows.request import parse_reader_options

    with errors_exit():
        reader = open_log(
            data, format, parse_reader_options(reader_option, topic=topic, fixed_frame=fixed_frame)
        )
        summary = summarize(reader, sequences.split(",") if sequences else None)
    print_log_summary(summary)


def print_log_summary(summary) -> None:
    """The sequences table and, for labelled logs, the class histogram."""
    from rich.console import Console
    from rich.table import Table

    console = Console(width=160)
    console.print(f"format: {summary.format}")
    table = Table(title="sequences")
    cols = (
        "sequence",
        "frames",
        "points",
        "points/frame",
        "no return",
        "sensor fields",
        "intensity",
        "poses",
    )
    for col in cols:
        table.add_column(col, justify="right")
    for seq, n in summary.frames.items():
        pts = summary.points[seq]
        source = summary.pose_source.get(seq)
        table.add_row(
            seq,
            str(n),
            str(pts),
            f"{pts / max(n, 1):.0f}",
            str(summary.no_return.get(seq, 0)),
            summary.fields.get(seq, ""),
            summary.intensity.get(seq, ""),
            source or "none (dsnet label --estimate-poses)",
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
