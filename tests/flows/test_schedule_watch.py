"""``dsnet serve`` says when its deployment's runs are not scheduled, are late, or fail: the watch
against the session's real (temporary) Prefect server, whose scheduler service does not run — the
very situation a broken scheduler produces."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

import pytest
from prefect import flow

from flows.schedule_watch import ScheduleWatch


@flow(name="watch-probe", persist_result=False)
def _probe() -> None:
    return None


@pytest.fixture
def deployment(prefect_api_url, request):
    from prefect.client.orchestration import get_client
    from prefect.client.schemas.actions import DeploymentScheduleCreate
    from prefect.client.schemas.schedules import CronSchedule

    name = f"dep-{request.node.name[-40:]}".replace("[", "-").replace("]", "")
    with get_client(sync_client=True) as client:
        flow_id = client.create_flow(_probe)
        dep_id = client.create_deployment(
            flow_id, name, schedules=[DeploymentScheduleCreate(schedule=CronSchedule(cron="* * * * *"))]
        )
        yield client, dep_id, f"watch-probe/{name}"


def test_a_deployment_with_no_scheduled_run_is_reported_once_then_its_recovery(deployment):
    from prefect.states import Scheduled

    client, dep_id, name = deployment
    lines: list[str] = []
    now = [0.0]
    watch = ScheduleWatch(name, lines.append, grace_s=60, clock=lambda: now[0])
    watch.check(client)
    assert lines == []  # within the grace period
    now[0] = 61.0
    watch.check(client)
    watch.check(client)
    assert len(lines) == 1 and f"scheduled no run of {name} in 61 s" in lines[0]
    assert "scheduler service is off or failing" in lines[0]
    soon = datetime.now(UTC) + timedelta(minutes=1)
    client.create_flow_run_from_deployment(dep_id, state=Scheduled(scheduled_time=soon))
    watch.check(client)
    assert lines[1] == f"runs of {name} are being scheduled again"


def test_a_late_and_a_failed_run_are_reported_with_their_reasons(deployment):
    from prefect.states import Failed, Scheduled

    client, dep_id, name = deployment
    lines: list[str] = []
    watch = ScheduleWatch(name, lines.append, grace_s=60)
    past = datetime.now(UTC) - timedelta(minutes=5)
    client.create_flow_run_from_deployment(dep_id, state=Scheduled(scheduled_time=past), name="late-one")
    failed = client.create_flow_run_from_deployment(dep_id, name="failed-one")
    client.set_flow_run_state(failed.id, Failed(message="watched log /x: no such folder"), force=True)
    watch.check(client)
    watch.check(client)  # each finding once
    assert any(ln.startswith("warning: scheduled run 'late-one'") and "s late" in ln for ln in lines)
    assert (
        f"warning: scheduled run 'failed-one' of {name} ended failed: watched log /x: no such folder" in lines
    )
    assert len(lines) == 2


def test_a_completed_tick_that_left_sequences_out_is_reported_with_its_message(deployment):
    from prefect.states import Completed

    client, dep_id, name = deployment
    lines: list[str] = []
    watch = ScheduleWatch(name, lines.append, grace_s=60)
    note = "labelled 1 sequence(s); not labelled, tried again next tick: 01: ingest: /x/000001.bin: truncated"
    for run_name, message in (
        ("partial-one", note),
        ("plain-one", None),
        ("stock-one", "All states completed."),
    ):
        run = client.create_flow_run_from_deployment(dep_id, name=run_name)
        client.set_flow_run_state(run.id, Completed(message=message), force=True)
    watch.check(client)
    watch.check(client)
    assert lines == [f"warning: scheduled run 'partial-one' of {name}: {note}"]
