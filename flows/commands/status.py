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
) -> None:
    """Per sequence and stage: done / damaged / partial (x of y blocks) / stale / missing, with
    fingerprints, then the run's report tables; the damaged files are listed under the table."""
    from rich.console import Console
    from rich.table import Table

    from storage.run import RunStore
    from tasks.run_config import RunConfig
    from tasks.runner import stage_state

    store = RunStore(root)
    with errors_exit():
        run = RunConfig.of(store.read_run_config())
        pipeline = run.pipeline()
    table = Table(title=f"run store {store.uri} (last run {run.run_id}, method {pipeline.name})")
    for col in ("sequence", "stage", "state", "blocks", "items", "fingerprint", "seconds"):
        table.add_column(col)
    damaged = []
    for seq in sorted(set(store.sequences()) | set(run.sequences)):
        for stage in pipeline.names():
            with errors_exit():
                state, m, n_done = stage_state(store, pipeline, seq, stage, run, full=verify)
                if state == "damaged":
                    damaged += store.check_stage(seq, pipeline[stage].contract, m, full=verify)
            if state == "partial":
                state = f"partial ({n_done} of {len(m.blocks)} blocks)"
            table.add_row(
                seq,
                stage,
                state,
                "" if m is None else f"{n_done}/{len(m.blocks)}",
                "" if m is None else str(m.n_items),
                "" if m is None else m.fingerprint,
                "" if m is None or not m.timings else f"{m.timings.get('wall_s', 0):.2f}",
            )
    damaged += _report_tables(store, table, verify)
    Console(width=140).print(table)
    for d in damaged[:20]:
        typer.echo(f"damaged: {d.where}: {d.problem}")
    if damaged:
        typer.echo(f"{len(damaged)} damaged files: `dsnet label` on this store recomputes them")


def _report_tables(store, table, verify: bool) -> list:
    """One row per report table the run wrote (``done``/``damaged``, sequence ``(run)``); their damage."""
    from flows.report.tables import REPORT_TABLES

    damaged = []
    for name, spec in REPORT_TABLES.items():
        if not store.has_table(spec):
            continue
        found = store.check_run_table(spec, full=verify)
        damaged += found
        table.add_row("(run)", f"table {name}", "damaged" if found else "done", "", "", "", "")
    return damaged
