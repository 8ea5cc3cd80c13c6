"""``dsnet label`` and ``dsnet status``. Heavy imports stay inside the bodies."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import typer

from flows.commands import options as o
from flows.commands.common import errors_exit, fail


@o.with_label_settings()
def label(
    ctx: typer.Context,
    data: str = typer.Argument(..., help="Log root (any supported format; see --format)."),
    run: str = typer.Option(..., "--run", help="Run store root: a folder or s3://bucket/prefix."),
    sequences: str = typer.Option(None, help="Comma-separated sequence names (default: all)."),
    format: o.Format = "auto",
    reader_option: o.ReaderOption = None,
    topic: o.Topic = None,
    fixed_frame: o.FixedFrame = None,
    method: o.MethodName = None,
    config: o.Config = None,
    overrides: o.Set = None,
    until: o.Until = None,
    from_stage: str = typer.Option(None, help="Recompute this stage and downstream.", rich_help_panel=o.RUN),
    force: bool = typer.Option(False, help="Recompute every stage.", rich_help_panel=o.RUN),
    on_error: str = typer.Option(
        "fail", help="fail: stop on a bad frame; skip: quarantine it and go on.", rich_help_panel=o.RUN
    ),
    block_size: int = typer.Option(25, min=1, help="Frames or volumes per task.", rich_help_panel=o.RUN),
    lock_wait: float = typer.Option(
        0.0, min=0.0, help="Seconds to wait for another run's lock.", rich_help_panel=o.RUN
    ),
    debug: bool = typer.Option(False, "--debug", help="Show Prefect's tracebacks.", rich_help_panel=o.RUN),
    workers: int = typer.Option(
        None, min=1, help="Blocks on a local Dask cluster of N processes.", rich_help_panel=o.SCALE
    ),
    dask_address: str = typer.Option(
        None, help="Blocks on a Dask scheduler (tcp://host:port).", rich_help_panel=o.SCALE
    ),
    settings: dict | None = None,
) -> None:
    """Label a log into a run store, resuming whatever is already done there (each method's stages:
    `dsnet config dump --method M`). Settings come from the method's defaults, then --config, then
    the flags given, then --set; the run folder keeps them as config.yaml."""
    from pathlib import Path

    if "://" not in data and not Path(data).expanduser().exists():  # before the heavy imports
        fail(f"{data}: no such file or folder")

    with errors_exit():
        if workers and dask_address:
            raise ValueError("give --workers or --dask-address, not both")
        request = o.configured_request(
            ctx, config, overrides, method, settings,
            dict(format=format, sequences=sequences, reader_option=reader_option, topic=topic,
                 fixed_frame=fixed_frame, on_error=on_error, block_size=block_size, lock_wait=lock_wait),
            data=data, root=run, from_stage=from_stage, until=until, force=force,
        )  # fmt: skip
    execute(request, workers, dask_address, debug)


def execute(request, workers: int | None, dask_address: str | None, debug: bool) -> None:
    """Check the services and the request, then label what is pending (nothing: no server at all)
    and print the run's summary; exit 1 when a sequence failed."""
    import time

    from flows.commands.label_report import run_report
    from flows.pending import pending_sequences
    from flows.preflight import check_content
    from flows.services import check_services

    with errors_exit():
        check_services(dask_address)  # PREFECT_API_URL and --dask-address, in seconds, before the rest
        request.check()
        pending = pending_sequences(request)
        check_content(request, pending)  # what `describe` would find, before any server starts
    t0 = time.monotonic()
    summary = run_label(request, workers, dask_address, debug=debug) if pending else []
    for line in run_report(request.root, summary, time.monotonic() - t0, request.storage_options):
        typer.echo(line)
    if any(r["action"] == "failed" for r in summary):
        raise typer.Exit(code=1)


def run_label(
    request, workers: int | None = None, dask_address: str | None = None, debug: bool = False
) -> list[dict]:
    """Run ``label-dataset`` for a :class:`~flows.request.LabelRequest` with progress bars, on the
    configured Prefect server or a temporary one; typed errors exit with code 2 and the message
    (Prefect's tracebacks only with ``debug``), Ctrl-C with code 130 and how to resume."""
    import os
    import sys

    from flows.server import prefect_api, quiet_prefect_env

    quiet_prefect_env()
    os.environ.setdefault("PREFECT_LOGGING_LEVEL", "WARNING")  # keep the progress bars readable
    if not os.environ.get("PREFECT_API_URL"):
        typer.echo(
            "starting a temporary Prefect server for this run (10-30 s; point PREFECT_API_URL at a "
            "running `prefect server start` to skip this)",
            err=True,
        )
    try:
        with _terminate_like_ctrl_c(), errors_exit(), prefect_api():
            from flows.label import label_dataset, task_runner

            if not debug:
                from flows.console import hide_tracebacks

                hide_tracebacks()
            flow = label_dataset.with_options(task_runner=task_runner(workers, dask_address))
            with _progress_bars():
                return flow(request)
    except KeyboardInterrupt:
        # the locks are released and the temporary server stopped (the with blocks unwound); blocks
        # still running in worker threads would keep this process alive until they finish (minutes
        # on a huge frame): leave now, the store keeps what was committed
        typer.secho(
            "error: interrupted; finished blocks are kept: run the same command again to resume",
            fg=typer.colors.RED,
            err=True,
        )
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(130)


@contextlib.contextmanager
def _terminate_like_ctrl_c() -> Iterator[None]:
    """SIGTERM (a scheduler's or ``kill``'s stop) takes Ctrl-C's clean way out while the flow runs
    (main thread only; the previous handler comes back after)."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, signal.default_int_handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _progress_bars():
    """Bars per stage counting frames (or volumes), with their rate and the time left."""
    from contextlib import contextmanager

    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        ProgressColumn,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )
    from rich.text import Text

    from flows.progress import BlockEvent, add_listener, emit, remove_listener
    from tasks.runner import ITEM_LISTENERS

    class Rate(ProgressColumn):
        def render(self, task) -> Text:
            speed = task.finished_speed or task.speed
            unit = task.fields.get("unit", "frames")
            return Text("" if speed is None else f"{speed:.1f} {unit}/s", style="progress.data.speed")

    def item_done(sequence: str, stage: str) -> None:
        emit(BlockEvent(stage, 0, 0, sequence, item=True))

    @contextmanager
    def bars():
        tasks: dict[str, int] = {}
        counted: dict[str, int] = {}
        columns = (TextColumn("{task.description:>8}"), BarColumn(), MofNCompleteColumn(), Rate())
        with Progress(*columns, TimeElapsedColumn(), TimeRemainingColumn()) as progress:

            def on_event(ev: BlockEvent) -> None:
                if ev.stage not in tasks:
                    if ev.item:
                        return
                    tasks[ev.stage] = progress.add_task(ev.stage, total=max(ev.total, 1), unit=ev.unit)
                    counted[ev.stage] = 0
                tid = tasks[ev.stage]
                if ev.item:  # one more item of a block running here
                    counted[ev.stage] += 1
                else:
                    counted[ev.stage] = max(counted[ev.stage], ev.done)
                    progress.update(tid, total=max(ev.total, 1))
                total = progress.tasks[tid].total or 1
                progress.update(
                    tid, completed=min(counted[ev.stage], total) if ev.total or ev.item else total
                )

            add_listener(on_event)
            ITEM_LISTENERS.append(item_done)
            try:
                yield
            finally:
                ITEM_LISTENERS.remove(item_done)
                remove_listener(on_event)

    return bars()


def print_stage_table(summary) -> None:
    """Per stage over all sequences: what was done, items, seconds (``dsnet demo``'s table)."""
    from rich.console import Console
    from rich.table import Table

    table = Table(title="label")
    for col in ("stage", "actions", "items", "points", "seconds"):
        table.add_column(col)
    stages: dict[str, dict] = {}
    for row in summary:
        if row.get("action") == "failed":
            continue
        s = stages.setdefault(row["stage"], {"actions": set(), "items": 0, "points": 0, "seconds": 0.0})
        s["actions"].add(row["action"])
        s["items"] += int(row.get("items") or 0)
        s["points"] += int(row.get("points") or 0)
        s["seconds"] += float(row.get("seconds") or 0.0)
    for name, s in stages.items():
        table.add_row(
            name, ", ".join(sorted(s["actions"])), str(s["items"]), str(s["points"]), f"{s['seconds']:.2f}"
        )
    Console(width=100).print(table)
