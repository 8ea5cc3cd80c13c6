"""``dsnet label`` and ``dsnet status``. Heavy imports stay inside the bodies."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import typer

from flows.commands import options as o
from flows.commands.common import errors_exit
from tasks.methods import DEFAULT_METHOD


def label(
    data: str = typer.Argument(..., help="Log root (any supported format; see --format)."),
    run: str = typer.Option(..., "--run", help="Run store root: a folder or s3://bucket/prefix."),
    sequences: str = typer.Option(None, help="Comma-separated sequence names (default: all)."),
    format: o.Format = "auto",
    reader_option: o.ReaderOption = None,
    topic: o.Topic = None,
    fixed_frame: o.FixedFrame = None,
    max_points: o.MaxPoints = None,
    estimate_poses: o.EstimatePoses = False,
    method: o.MethodName = DEFAULT_METHOD,
    scans: o.Scans = None,
    stride: o.Stride = None,
    clusterer: o.Clusterer = None,
    temporal: o.Temporal = "auto",
    refine: o.Refine = None,
    semantic_prior: o.SemanticPrior = None,
    prior_label_map: o.PriorLabelMap = None,
    checkpoint: o.Checkpoint = None,
    device: o.Device = None,
    tta: o.Tta = 1,
    tta_flip: o.TtaFlip = False,
    equivariant: o.Equivariant = None,
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
) -> None:
    """Label a log into a run store, resuming whatever is already done there (dsnet: ingest → align →
    infer → shift → fuse → stitch|track → score; most: … → most → track → score; dpls: … → prior →
    dpls → shift → fuse → stitch|track → score)."""
    from flows.request import LabelRequest, parse_reader_options

    with errors_exit():
        if workers and dask_address:
            raise ValueError("give --workers or --dask-address, not both")
        settings = o.label_settings(
            scans, stride, checkpoint, clusterer, estimate_poses, max_points, device, tta, tta_flip,
            equivariant, semantic_prior, prior_label_map, temporal, refine,
        )  # fmt: skip
        request = LabelRequest.from_settings(
            settings,
            data=data,
            root=run,
            sequences=sequences.split(",") if sequences else None,
            format=format,
            reader_options=parse_reader_options(reader_option, topic=topic, fixed_frame=fixed_frame),
            method=method,
            options={"on_error": on_error, "block_size": block_size, "lock_wait_s": lock_wait},
            from_stage=from_stage,
            until=until,
            force=force,
        )
        from flows.services import check_services

        check_services(dask_address)  # PREFECT_API_URL and --dask-address, in seconds, before the rest
        request.check()
    summary = run_label(request, workers, dask_address, debug=debug)
    print_summary(summary)
    typer.echo(f"wrote run store {run}")
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
    from contextlib import contextmanager

    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from flows.progress import add_listener, remove_listener

    @contextmanager
    def bars():
        bars_by_stage = {}
        with Progress(
            TextColumn("{task.description:>8}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn()
        ) as progress:

            def on_event(ev) -> None:
                if ev.stage not in bars_by_stage:
                    bars_by_stage[ev.stage] = progress.add_task(ev.stage, total=max(ev.total, 1))
                tid = bars_by_stage[ev.stage]
                progress.update(tid, total=max(ev.total, 1), completed=ev.done if ev.total else 1)

            add_listener(on_event)
            try:
                yield
            finally:
                remove_listener(on_event)

    return bars()


def print_summary(summary) -> None:
    """The label run's summary table (one row per sequence and stage)."""
    from rich.console import Console
    from rich.table import Table

    table = Table(title="label")
    cols = ("sequence", "stage", "action", "blocks_run", "items", "points", "seconds", "fingerprint")
    for col in cols:
        table.add_column(col)
    for row in summary:
        table.add_row(*[str(row.get(c, "")) for c in cols])
    Console(width=140).print(table)
