"""``dsnet label`` and ``dsnet status``. Heavy imports stay inside the bodies."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import typer

from flows.commands.common import (
    FIXED_FRAME_HELP,
    FORMAT_HELP,
    READER_OPTION_HELP,
    TOPIC_HELP,
    errors_exit,
)


def label(
    data: str = typer.Argument(..., help="Log root (any supported format; see --format)."),
    run: str = typer.Option(..., "--run", help="Run store root: a folder or s3://bucket/prefix."),
    sequences: str = typer.Option(None, help="Comma-separated sequence names (default: all)."),
    format: str = typer.Option("auto", "--format", help=FORMAT_HELP),
    reader_option: list[str] = typer.Option(None, "--reader-option", help=READER_OPTION_HELP),
    topic: str = typer.Option(None, "--topic", help=TOPIC_HELP),
    fixed_frame: str = typer.Option(None, "--fixed-frame", help=FIXED_FRAME_HELP),
    max_points: int = typer.Option(
        None, "--max-points", min=1, help="Refuse frames with more points (default 2,000,000): memory guard."
    ),
    method: str = typer.Option("dsnet", "--method", help="Labelling method (see the README's method table)."),
    scans: int = typer.Option(
        None,
        min=1,
        max=16,
        help="k: scans per 4D volume for dsnet and dpls (1 = 3D, default 2); for most the current scan "
        "plus k-1 past scans (default 3).",
    ),
    stride: int = typer.Option(None, min=1, help="Step between volumes (default k-1, or 1 for k=1)."),
    checkpoint: str = typer.Option(None, help="Model checkpoint folder (default: the bundled demo model)."),
    clusterer: str = typer.Option(
        None, help="dynamic_shift (default), meanshift, dbscan, hdbscan or bfs; or a JSON clusterer config."
    ),
    estimate_poses: bool = typer.Option(
        False,
        "--estimate-poses",
        help="Estimate LiDAR poses by KISS-ICP odometry for sequences without poses.txt (needs the "
        "[odometry] extra); a log's own poses always win.",
    ),
    until: str = typer.Option(None, help="Stop after this stage (e.g. align)."),
    from_stage: str = typer.Option(None, help="Recompute this stage and everything downstream."),
    force: bool = typer.Option(False, help="Recompute every stage."),
    on_error: str = typer.Option("fail", help="fail: stop on a bad frame; skip: quarantine it and go on."),
    workers: int = typer.Option(
        None, min=1, help="Run blocks on a local Dask cluster of N worker processes."
    ),
    dask_address: str = typer.Option(
        None, help="Run blocks on an existing Dask scheduler (tcp://host:port)."
    ),
    block_size: int = typer.Option(25, min=1, help="Frames or volumes per task."),
    lock_wait: float = typer.Option(
        0.0, min=0.0, help="Seconds to wait for another run's lock before failing."
    ),
    debug: bool = typer.Option(False, "--debug", help="Show Prefect's tracebacks of failing tasks."),
    temporal: str = typer.Option(
        "auto",
        "--temporal",
        help="Sequence-wide ids: stitch (overlapping volumes, k > 1), track (each frame's instances "
        "tracked by centre) or auto (track at --scans 1, else stitch).",
    ),
    device: str = typer.Option(
        None, "--device", help="The model's torch device: cpu (default), cuda, cuda:1."
    ),
    tta: int = typer.Option(
        1, "--tta", min=1, max=64, help="Test-time augmentation: average over N yaw rotations (1: off)."
    ),
    tta_flip: bool = typer.Option(False, "--tta-flip", help="With --tta: also average the mirror images."),
    equivariant: int = typer.Option(
        None, "--equivariant", min=1, help="Require a C_n-equivariant checkpoint trained with this n."
    ),
    semantic_prior: str = typer.Option(
        None,
        "--semantic-prior",
        help="dpls: folder of per-scan semantic predictions of any network (DIR/sequences/SEQ/predictions/"
        "ID.label or .npy, or DIR/SEQ/ID.label|.npy); default: the bundled model's semantics.",
    ),
    prior_label_map: str = typer.Option(
        None,
        "--prior-label-map",
        help="dpls: label map of the --semantic-prior files, a bundled name or a YAML "
        "(default: the log's own).",
    ),
) -> None:
    """Label a log into a run store (dsnet: ingest → align → infer → shift → fuse → stitch|track →
    score; most: ingest → align → most → track → score; dpls: ingest → align → prior → dpls → shift →
    fuse → stitch|track → score), resuming whatever is already done there."""
    if on_error not in ("fail", "skip"):
        raise typer.BadParameter("--on-error must be 'fail' or 'skip'")
    if workers and dask_address:
        raise typer.BadParameter("give --workers or --dask-address, not both")
    if scans is None:
        scans = 3 if method == "most" else 2
    from flows.request import LabelRequest, parse_reader_options, stage_settings

    with errors_exit():
        request = LabelRequest(
            data=data,
            root=run,
            sequences=sequences.split(",") if sequences else None,
            format=format,
            reader_options=parse_reader_options(reader_option, topic=topic, fixed_frame=fixed_frame),
            method=method,
            method_options={} if temporal == "auto" else {"temporal": temporal},
            stages=stage_settings(
                scans,
                stride,
                checkpoint,
                clusterer,
                estimate_poses,
                max_points,
                device,
                tta,
                tta_flip,
                equivariant,
                method,
                semantic_prior,
                prior_label_map,
            ),
            options={"on_error": on_error, "block_size": block_size, "lock_wait_s": lock_wait},
            from_stage=from_stage,
            until=until,
            force=force,
        )
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
    from tasks.methods import run_pipeline
    from tasks.runner import stage_state

    store = RunStore(root)
    with errors_exit():
        run = store.read_run_config()
        pipeline = run_pipeline(run)
    table = Table(title=f"run store {store.uri} (last run {run.get('run_id')}, method {pipeline.name})")
    for col in ("sequence", "stage", "state", "blocks", "items", "fingerprint", "seconds"):
        table.add_column(col)
    damaged = []
    for seq in sorted(set(store.sequences()) | set(run.get("sequences", []))):
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
