"""``dsnet dashboard``: the evaluation dashboard of one or more scored run stores."""

from __future__ import annotations

from pathlib import Path

import typer


def dashboard(
    roots: list[str] = typer.Argument(..., help="Run store roots; the first is the baseline (A) for deltas."),
    out: Path = typer.Option(Path("dashboard.html"), "--out", help="HTML file to write."),
    title: str = typer.Option("dsnet evaluation", help="Page title."),
) -> None:
    """Write a self-contained HTML dashboard (works offline) from the runs' score tables."""
    from flows.dashboard import build_dashboard
    from storage.errors import StoreError

    try:
        path = build_dashboard(roots, out, title)
    except StoreError as exc:
        typer.secho(f"error: {exc}", fg=typer.colors.RED, err=True)
        raise typer.Exit(code=2) from None
    typer.echo(f"wrote dashboard {path.resolve()}")
