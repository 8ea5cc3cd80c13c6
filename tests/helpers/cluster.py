"""A real Dask cluster for tests: ``dask scheduler`` and ``dask worker`` processes on loopback.

Every process binds 127.0.0.1 (scheduler, workers and their dashboards), gets the caller's
environment (``PYTHONPATH``, ``PREFECT_API_URL``, ``AWS_*`` for a loopback S3 store), and is
started in its own process group so it can be SIGKILLed alone (a lost worker) and is always
stopped. Workers run without a nanny, so a killed worker stays dead and the scheduler must
reschedule its tasks on the others.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

_SCHEDULER = [sys.executable, "-m", "dask", "scheduler"]  # ``dask scheduler`` of this interpreter
_WORKER = [sys.executable, "-m", "dask", "worker"]


@dataclass
class DaskCluster:
    """Handles of a running cluster.

    Attributes:
        address: ``tcp://127.0.0.1:PORT`` of the scheduler.
        scheduler: the scheduler process.
        workers: worker processes, by name (``w0``, ``w1``, ...).
        logs: folder of each process's combined stdout/stderr (``NAME.log``).
    """

    address: str
    scheduler: subprocess.Popen
    workers: dict[str, subprocess.Popen] = field(default_factory=dict)
    logs: Path = Path(".")
    env: dict[str, str] = field(default_factory=dict)

    def kill_worker(self, name: str) -> int:
        """SIGKILL one worker (a lost machine); returns its pid."""
        proc = self.workers[name]
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
        return proc.pid

    def add_worker(self, name: str) -> subprocess.Popen:
        """Start one more worker (1 thread, no nanny) and wait until the scheduler sees it."""
        before = self.n_workers()
        log = open(self.logs / f"{name}.log", "wb")
        proc = subprocess.Popen(
            [*_WORKER, self.address, "--name", name, "--nthreads", "1", "--no-nanny",
             "--host", "127.0.0.1", "--dashboard-address", "127.0.0.1:0", "--death-timeout", "60"],
            env=self.env, stdout=log, stderr=subprocess.STDOUT, start_new_session=True,
        )  # fmt: skip
        self.workers[name] = proc
        _wait(lambda: self.n_workers() > before, 120, f"worker {name} to register", proc, self.logs)
        return proc

    def replace_dead_workers(self) -> None:
        """Start a fresh worker for each one that has exited (after a kill), keeping the cluster whole."""
        for name, proc in list(self.workers.items()):
            if proc.poll() is not None:
                self.add_worker(name)

    def busy_worker(self) -> str | None:
        """The name of a worker that is running a task now (None when none is)."""
        from distributed import Client

        with Client(self.address, timeout=10) as client:
            processing = client.processing()
            names = {addr: w["name"] for addr, w in client.scheduler_info(n_workers=-1)["workers"].items()}
        busy = sorted(names[a] for a, tasks in processing.items() if tasks and a in names)
        return str(busy[0]) if busy else None

    def n_workers(self) -> int:
        """Workers the scheduler knows now (asked through a short-lived client)."""
        from distributed import Client

        with Client(self.address, timeout=10) as client:
            return len(client.scheduler_info(n_workers=-1)["workers"])

    def worker_log(self, name: str) -> str:
        return (self.logs / f"{name}.log").read_text(errors="replace")

    def stop(self) -> None:
        for proc in [*self.workers.values(), self.scheduler]:
            if proc.poll() is None:
                try:
                    os.killpg(proc.pid, signal.SIGTERM)
                except ProcessLookupError:
                    continue
        for proc in [*self.workers.values(), self.scheduler]:
            try:
                proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait(timeout=10)


def start_cluster(logs: Path, env: dict[str, str], n_workers: int = 2) -> DaskCluster:
    """Start a scheduler and ``n_workers`` single-threaded workers on loopback.

    Args:
        logs: a folder for the processes' logs and the scheduler file.
        env: environment of every process (this checkout on ``PYTHONPATH``, the Prefect API, S3).
    """
    logs.mkdir(parents=True, exist_ok=True)
    sched_file = logs / "scheduler.json"
    log = open(logs / "scheduler.log", "wb")
    scheduler = subprocess.Popen(
        [*_SCHEDULER, "--host", "127.0.0.1", "--port", "0", "--dashboard-address", "127.0.0.1:0",
         "--scheduler-file", str(sched_file), "--idle-timeout", "3600"],
        env=env, stdout=log, stderr=subprocess.STDOUT, start_new_session=True,
    )  # fmt: skip
    cluster = DaskCluster(address="", scheduler=scheduler, logs=logs, env=env)
    try:
        _wait(lambda: _read_address(sched_file) is not None, 120, "the scheduler file", scheduler, logs)
        cluster.address = str(_read_address(sched_file))
        for i in range(n_workers):
            cluster.add_worker(f"w{i}")
    except BaseException:
        cluster.stop()
        raise
    return cluster


def _read_address(path: Path) -> str | None:
    try:
        return json.loads(path.read_text())["address"]
    except (OSError, ValueError, KeyError):
        return None


def _wait(cond, timeout: float, what: str, proc: subprocess.Popen, logs: Path) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            tails = {p.name: p.read_text(errors="replace")[-2000:] for p in logs.glob("*.log")}
            raise RuntimeError(f"process ended (rc {proc.returncode}) before {what}: {tails}")
        try:
            if cond():
                return
        except OSError:
            pass
        time.sleep(0.2)
    raise TimeoutError(f"timed out waiting for {what}")
