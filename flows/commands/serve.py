"""``dsnet serve``: the scheduled auto-labelling deployment."""

from __future__ import annotations

import os
from pathlib import Path

import typer

from flows.commands.common import (
    FIXED_FRAME_HELP,
    FORMAT_HELP,
    READER_OPTION_HELP,
    TOPIC_HELP,
    errors_exit,
    fail,
)


def serve(
    watch: Path = typer.Option(
        ..., "--watch", help="Log root to watch (any format: each scene, scan folder or bag is a sequence)."
    ),
    format: str = typer.Option("auto", "--format", help=FORMAT_HELP),
    reader_option: list[str] = typer.Option(None, "--reader-option", help=READER_OPTION_HELP),
    topic: str = typer.Option(None, "--topic", help=TOPIC_HELP),
    fixed_frame: str = typer.Option(None, "--fixed-frame", help=FIXED_FRAME_HELP),
    max_points: int = typer.Option(
        None, "--max-points", min=1, help="Refuse frames with more points (default 2,000,000): memory guard."
    ),
    runs: str = typer.Option(..., "--runs", help="Run store root the labels and scores go to."),
    cron: str = typer.Option("0 * * * *", "--cron", help="When to look for new or stale sequences (cron)."),
    name: str = typer.Option(
        None, help="Dataset name (artifact keys, deployment name); default: the log's folder."
    ),
    method: str = typer.Option(
        "dsnet", "--method", help="Labelling method: dsnet, most or dpls (as dsnet label)."
    ),
    semantic_prior: str = typer.Option(None, "--semantic-prior", help="dpls: prior files (as dsnet label)."),
    prior_label_map: str = typer.Option(
        None, "--prior-label-map", help="dpls: their label map (as dsnet label)."
    ),
    scans: int = typer.Option(None, help="k as in dsnet label (default 2 for dsnet, 3 for most)."),
    checkpoint: str = typer.Option(None, help="Model checkpoint folder (default: the bundled model)."),
    until: str = typer.Option(None, help="Stop after this stage (default: run every stage)."),
    estimate_poses: bool = typer.Option(
        False, "--estimate-poses", help="KISS-ICP poses for sequences without poses.txt (log poses win)."
    ),
    check_every: float = typer.Option(
        30.0,
        "--check-every",
        min=1.0,
        help="Seconds between checks that the server schedules this deployment's runs and that they "
        "succeed (a warning line when not).",
    ),
) -> None:
    """Serve a Prefect deployment that labels, scores and publishes new or stale sequences on a schedule.

    Needs a Prefect server: `prefect server start --host 127.0.0.1` and PREFECT_API_URL pointing at it.
    """
    from flows.server import quiet_prefect_env

    quiet_prefect_env()
    if not os.environ.get("PREFECT_API_URL"):
        fail(
            "schedules need a Prefect server: run `prefect server start --host 127.0.0.1` and "
            "export PREFECT_API_URL=http://127.0.0.1:4200/api"
        )
    from flows.request import LabelRequest, parse_reader_options, stage_settings
    from flows.watch import serve as serve_deployment

    with errors_exit():
        request = LabelRequest(
            data=str(watch.resolve()),
            root=runs,
            format=format,
            reader_options=parse_reader_options(reader_option, topic=topic, fixed_frame=fixed_frame),
            method=method,
            stages=stage_settings(
                scans or (3 if method == "most" else 2),
                checkpoint=checkpoint,
                estimate_poses=estimate_poses,
                max_points=max_points,
                method=method,
                semantic_prior=semantic_prior,
                prior_label_map=prior_label_map,
            ),
            until=until,
        )
        request.order(request.pipeline())  # unknown stages fail now, not at the first tick
        request.open_log()  # so do an unknown format or reader option
    typer.echo(f"serving auto-label of {watch.resolve()} into {runs} on cron '{cron}' (Ctrl-C stops)")
    with errors_exit():
        serve_deployment(
            request,
            cron,
            name,
            say=lambda line: typer.echo(line, err=True),
            check_every_s=check_every,
            grace_s=max(150.0, 3 * check_every),
        )
