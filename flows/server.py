"""Prefect API for one process: the configured server, or a temporary one that dies with us.

Prefect's own temporary server is a child process stopped by ``atexit``; a SIGKILLed parent
leaves it running. Ours asks the kernel (``PR_SET_PDEATHSIG``) to SIGTERM it when its parent
dies, so a killed ``dsnet label`` or test session never orphans a server.

This is the one module that relies on Prefect internals (``SubprocessASGIServer`` and its private
``_run_uvicorn_command``, the ``PREFECT__SERVER_*`` variables, ``EventsWorker.drain_all``);
``tests/flows/test_prefect_pins.py`` pins each, so an upgrade that changes one fails by name.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import signal
import socket
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

QUIET_DEFAULTS = {
    "PREFECT_SERVER_ANALYTICS_ENABLED": "false",
    "PREFECT_LOGGING_TO_API_ENABLED": "false",
    "PREFECT_SERVER_UI_ENABLED": "false",
    "PREFECT_RESULTS_PERSIST_BY_DEFAULT": "false",
}


def quiet_prefect_env() -> None:
    """Analytics, API logging and the UI off unless the user set them (call before importing prefect)."""
    for key, value in QUIET_DEFAULTS.items():
        os.environ.setdefault(key, value)


def _free_port() -> int:
    with contextlib.closing(socket.socket(socket.AF_INET, socket.SOCK_STREAM)) as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def _die_with_parent() -> None:  # runs in the child between fork and exec
    libc = ctypes.CDLL(None, use_errno=True)
    libc.prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG


def _server_log():
    """The temporary server's log file (``$PREFECT_HOME/temporary-server.log``, rewritten per start)."""
    from prefect.settings import get_current_settings

    home = Path(get_current_settings().home).expanduser()
    home.mkdir(parents=True, exist_ok=True)
    return open(home / "temporary-server.log", "wb")


def _owned_server_class():
    import prefect
    from prefect.server.api.server import SubprocessASGIServer
    from prefect.settings import get_current_settings

    class OwnedServer(SubprocessASGIServer):
        """Prefect's temporary server, started with PR_SET_PDEATHSIG."""

        def _run_uvicorn_command(self) -> subprocess.Popen:
            env = {
                **os.environ,
                "PREFECT_UI_ENABLED": "0",
                "PREFECT__SERVER_EPHEMERAL": "1",
                "PREFECT__SERVER_FINAL": "1",
                **get_current_settings().to_environment_variables(exclude_unset=True),
            }
            with _server_log() as log:  # the child keeps its own descriptor
                return subprocess.Popen(
                    [
                        sys.executable,
                        "-m",
                        "uvicorn",
                        "--app-dir",
                        str(prefect.__module_path__.parent),
                        "--factory",
                        "prefect.server.api.server:create_app",
                        "--host",
                        "127.0.0.1",
                        "--port",
                        str(self.port),
                        "--log-level",
                        "error",
                        "--lifespan",
                        "on",
                    ],
                    env=env,
                    preexec_fn=_die_with_parent if sys.platform.startswith("linux") else None,
                    # its own session: a Ctrl-C at the terminal reaches dsnet, which stops the server
                    # after the flow has reported its state, never the server first
                    start_new_session=True,
                    # its request errors (e.g. a client cancelled by Ctrl-C) go to a file, not the terminal
                    stdout=log,
                    stderr=log,
                )

    return OwnedServer


@contextlib.contextmanager
def prefect_api(startup_timeout: int = 90) -> Iterator[str]:
    """Yield the API URL to use: ``PREFECT_API_URL`` if set, else a temporary loopback server's.

    The temporary server is stopped on exit and dies with this process if it is killed.
    ``PREFECT_API_URL`` is exported for child processes (Dask workers) while it runs.
    """
    quiet_prefect_env()
    existing = os.environ.get("PREFECT_API_URL")
    if existing:
        from flows.services import check_prefect_api

        check_prefect_api(existing)
        yield existing
        return
    from prefect.settings import PREFECT_API_URL, temporary_settings

    server = _owned_server_class()(port=_free_port())
    server.start(timeout=startup_timeout)
    os.environ["PREFECT_API_URL"] = server.api_url
    try:
        with temporary_settings(updates={PREFECT_API_URL: server.api_url}):
            yield server.api_url
    finally:
        os.environ.pop("PREFECT_API_URL", None)
        _drain_events()
        server.stop()


def _drain_events(timeout: float = 10.0) -> None:
    """Flush and stop Prefect's events worker while its server still runs: the worker is a process
    singleton bound to the URL it started with, so a later temporary server in the same process
    would otherwise see a worker that keeps retrying the dead one."""
    from prefect.events.worker import EventsWorker

    EventsWorker.drain_all(timeout=timeout, at_exit=False)
