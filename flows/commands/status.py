"""``dsnet status``: per sequence and stage, what a run store holds."""

from __future__ import annotations

import typer

from flows.commands.common import errors_exit


def status(
    root: str = typer.Argument(..., help="Run store root (folder or s3://…)."),
    verify: bool = typer.Option(
        False,
        "--verify",
        help="Decode every chunk and table file and compare checksums (reads the whole store), "
        "instead of checking that each file is there with the size it was written with.",
    ),
    verbose: bool = typer.Option(
        False, "--verbose", "-v", help="Also the bytes each stage stores, in all and per frame."
    ),
) -> None:
    """Per sequence and stage: done / damaged / running / interrupted / failed / stale / missing,
    with finished blocks and fingerprints, then the run's report tables; the damaged files are listed
    under the table. A stage is stale when the log has frames the run has not (or lost some)."""
    from rich.console import Console
    from rich.table import Table

    from flows.status_view import StatusView

    with errors_exit():
        view = StatusView.open(root, verify)
    table = Table(
        title=f"run store {view.store.uri} (last run {view.run.run_id}, method {view.pipeline.name})"
    )
    columns = ["sequence", "stage", "state", "blocks done", "items", "fingerprint", "seconds"]
    for col in columns + (["bytes", "bytes/frame"] if verbose else []):
        table.add_column(col)
    with errors_exit():
        for row in view.rows(verbose):
            table.add_row(*row)
    for row in view.report_rows(verbose) + view.dashboard_row(verbose):
        table.add_row(*row)
    Console(width=160 if verbose else 140).print(table)
    from flows.commands.label_report import headline

    typer.echo(headline(view.store))
    for line in view.notes(verbose):
        typer.echo(line)
