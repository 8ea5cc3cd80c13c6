"""``dsnet dashboard``: the dashboard of one or more run stores (labelled, and scored where the log
has ground truth)."""

from __future__ import annotations

from pathlib import Path

import typer

from flows.commands.common import check_output, errors_exit


def dashboard(
    roots: list[str] = typer.Argument(..., help="Run store roots; the first is the baseline (A) for deltas."),
    out: Path = typer.Option(Path("dashboard.html"), "--out", help="HTML file to write."),
    title: str = typer.Option("dsnet run report", help="Page title."),
) -> None:
    """Write a self-contained HTML dashboard (works offline) from the runs' report tables: what was
    labelled, confidence, tracks, refinement, timings, the review queue, and the scores where the
    log has ground truth. A run whose report is missing or older than its stages gets it rewritten;
    a run still in progress is named with the stage it is at, on the page and here."""
    from flows.dashboard import build_dashboard
    from flows.dashboard.data import run_progress
    from flows.publish import refresh_report
    from storage.run import RunStore

    with errors_exit():
        check_output(out, "--out", "file")
        for root in roots:
            refresh_report(root)
        path = build_dashboard(roots, out, title)
        unfinished = [(root, run_progress(RunStore(root))) for root in roots]
    typer.echo(f"wrote dashboard {path.resolve()}")
    for root, where in unfinished:
        if where:
            typer.echo(f"note: {root}: the run is in progress: {where}; the page shows what is done so far")
