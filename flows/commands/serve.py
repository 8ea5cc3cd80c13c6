"""``dsnet serve``: the scheduled auto-labelling deployment."""

from __future__ import annotations

import os
from pathlib import Path

import typer

from flows.commands import options as o
from flows.commands.common import errors_exit, fail


@o.with_label_settings()
def serve(
    ctx: typer.Context,
    watch: Path = typer.Option(
        ..., "--watch", help="Log root to watch (any format: each scene, scan folder or bag is a sequence)."
    ),
    runs: str = typer.Option(..., "--runs", help="Run store root the labels and scores go to."),
    cron: str = typer.Option("0 * * * *", "--cron", help="When to look for new or stale sequences (cron)."),
    name: str = typer.Option(
        None, help="Dataset name (artifact keys, deployment name); default: the log's folder."
    ),
    format: o.Format = "auto",
    reader_option: o.ReaderOption = None,
    topic: o.Topic = None,
    fixed_frame: o.FixedFrame = None,
    method: o.MethodName = None,
    config: o.Config = None,
    overrides: o.Set = None,
    until: o.Until = None,
    check_every: float = typer.Option(
        30.0,
        "--check-every",
        min=1.0,
        help="Seconds between checks that the server schedules this deployment's runs and that they "
        "succeed (a warning line when not).",
    ),
    settings: dict | None = None,
) -> None:
    """Serve a Prefect deployment that labels, scores and publishes new or stale sequences on a schedule.

    Needs a Prefect server: `prefect server start --host 127.0.0.1` and PREFECT_API_URL pointing at it.
    Takes the label settings, --config and --set of `dsnet label`.
    """
    from flows.server import quiet_prefect_env

    quiet_prefect_env()
    with errors_exit():  # the settings first: a bad one is refused without a server
        request = o.configured_request(
            ctx, config, overrides, method, settings,
            dict(format=format, reader_option=reader_option, topic=topic, fixed_frame=fixed_frame),
            data=str(watch.resolve()), root=runs, until=until,
        )  # fmt: skip
    if not os.environ.get("PREFECT_API_URL"):
        fail(
            "schedules need a Prefect server: run `prefect server start --host 127.0.0.1` and "
            "export PREFECT_API_URL=http://127.0.0.1:4200/api"
        )
    with errors_exit():
        from flows.services import check_prefect_api

        check_prefect_api(os.environ["PREFECT_API_URL"])
        request.check()  # a bad method, stage, format, option or model fails now, not at the first tick
        check_cron(cron)
    from flows.watch import serve as serve_deployment

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


def check_cron(cron: str) -> None:
    """Raise ValueError naming ``--cron`` when it is not a cron expression Prefect takes."""
    from prefect.client.schemas.schedules import CronSchedule
    from pydantic import ValidationError

    try:
        CronSchedule(cron=cron)
    except ValidationError as exc:
        reason = exc.errors()[0].get("msg", "invalid").removeprefix("Value error, ")
        raise ValueError(f"--cron: {reason} (five fields: minute hour day month weekday)") from None
