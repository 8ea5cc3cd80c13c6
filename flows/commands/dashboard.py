"""``dsnet dashboard``: the evaluation dashboard of one or more scored run stores."""

from __future__ import annotations

from pathlib import Path

import typer

from flows.commands.common import check_output, errors_exit


def dashboard(
    roots: list[str] = typer.Argument(..., help="Run store roots; the first is the baseline (A) for deltas."),
    out: Path = typer.Option(Path("dashboard.html"), "--out", help="HTML file to write."),
    title: str = typer.Option("dsnet evaluation", help="Page title."),
) -> None:
    """Write a self-contained HTML dashboard (works offline) from the runs' score tables."""
    from flows.dashboard import build_dashboard

    with errors_exit():
        check_output(out, "--out", "file")
        path = build_dashboard(roots, out, title)
    typer.echo(f"wrote dashboard {path.resolve()}")
