"""``dsnet serve``'s look at its own deployment: are runs being scheduled, and do they succeed?

Prefect's server creates a deployment's scheduled runs in a background service; when that service
fails (as it did with SQLAlchemy 2.1: "Can't evaluate bulk DML statement" every minute), the
served process waits forever and nothing says why. :class:`ScheduleWatch` polls the API from a
daemon thread and prints one line when

- no run of the deployment is scheduled ahead, ``grace_s`` after serving began (the server's
  scheduler service is off or failing: its log says why),
- a run is late (scheduled, its start time passed by more than ``grace_s``: no runner picks it
  up),
- a run ends failed or crashed (its state message),
- a run ends completed with a message (a tick that left sequences out: which, and why),
- a tick ends completed (``tick 'NAME' of …: labelled 2 sequence(s): 00, 01 · PQ …``: its one line),

and one line when scheduling recovers.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from datetime import UTC, datetime, timedelta

FAILED = ("FAILED", "CRASHED")
STOCK = ("", "All states completed.")
"""Completion messages that say nothing (Prefect's own)."""


class ScheduleWatch:
    """Polls the flow runs of one deployment and reports what is wrong, once per finding.

    Args:
        deployment: ``flow-name/deployment-name``.
        say: where lines go (``typer.echo`` to stderr in the CLI).
        every_s: seconds between polls.
        grace_s: how long a served deployment may have no run scheduled ahead, and how late a
            scheduled run may be, before it is reported (Prefect's scheduler loop runs every 60 s).
    """

    def __init__(
        self,
        deployment: str,
        say: Callable[[str], None],
        every_s: float = 30.0,
        grace_s: float = 150.0,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.deployment, self.say, self.every_s, self.grace_s, self.clock = (
            deployment,
            say,
            every_s,
            grace_s,
            clock,
        )
        self.started = clock()
        self.reported: set[str] = set()
        self.unscheduled = False
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> ScheduleWatch:
        self._thread = threading.Thread(target=self._loop, name="dsnet-schedule-watch", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()

    def _loop(self) -> None:
        from prefect.client.orchestration import get_client

        with get_client(sync_client=True) as client:
            while not self._stop.wait(self.every_s):
                try:
                    self.check(client)
                except Exception as exc:  # the API away for a moment must not kill serving
                    self._once("api", f"warning: cannot read the runs of {self.deployment}: {exc}")

    def _once(self, key: str, line: str) -> None:
        if key not in self.reported:
            self.reported.add(key)
            self.say(line)

    def check(self, client) -> None:
        """One poll: read the deployment's runs and report new findings."""
        from prefect.client.schemas.filters import DeploymentFilter, DeploymentFilterId
        from prefect.client.schemas.sorting import FlowRunSort

        try:
            dep = client.read_deployment_by_name(self.deployment)
        except Exception:  # not registered yet (serve registers it as it starts)
            return
        runs = client.read_flow_runs(
            deployment_filter=DeploymentFilter(id=DeploymentFilterId(any_=[dep.id])),
            sort=FlowRunSort.EXPECTED_START_TIME_DESC,
            limit=50,
        )
        now = datetime.now(UTC)
        for run in runs:
            state = run.state
            if state is None:
                continue
            if state.type.value in FAILED:
                message = (state.message or "").strip().splitlines()
                self._once(
                    f"failed:{run.id}",
                    f"warning: scheduled run {run.name!r} of {self.deployment} ended {state.name.lower()}"
                    f": {message[-1] if message else 'no message'}",
                )
            elif state.type.value == "COMPLETED" and (state.message or "").strip() not in STOCK:
                message = state.message.strip()
                clean = message.startswith("labelled") and "not labelled" not in message
                self._once(  # a clean tick's one line, or what it left out
                    f"note:{run.id}",
                    f"{'tick' if clean else 'warning: scheduled run'} {run.name!r} of {self.deployment}: "
                    f"{message}",
                )
            elif state.type.value == "SCHEDULED" and run.expected_start_time is not None:
                late = now - run.expected_start_time
                if late > timedelta(seconds=self.grace_s):
                    self._once(
                        f"late:{run.id}",
                        f"warning: scheduled run {run.name!r} of {self.deployment} is "
                        f"{late.total_seconds():.0f} s late: no runner has picked it up",
                    )
        ahead = [
            r
            for r in runs
            if (r.state is not None and r.state.type.value in ("SCHEDULED", "PENDING", "RUNNING"))
            or (r.expected_start_time is not None and r.expected_start_time > now - timedelta(minutes=2))
        ]
        if not ahead and self.clock() - self.started > self.grace_s and dep.schedules:
            if not self.unscheduled:
                self.unscheduled = True
                self.say(
                    f"warning: the Prefect server has scheduled no run of {self.deployment} in "
                    f"{self.clock() - self.started:.0f} s: its scheduler service is off or failing "
                    "(see the server's log; `prefect server start` runs it, a temporary server does not)"
                )
        elif ahead and self.unscheduled:
            self.unscheduled = False
            self.say(f"runs of {self.deployment} are being scheduled again")
