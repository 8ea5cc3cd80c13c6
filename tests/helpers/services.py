"""Real services for slow tests, on loopback, each in its own temporary folder and always stopped:
``prefect server start`` (SQLite, or a PostgreSQL database) and a PostgreSQL cluster made with
``initdb`` and ``pg_ctl`` (Debian's ``postgresql`` package; a session's processes end with it, so
the test makes its own cluster)."""

from __future__ import annotations

import contextlib
import glob
import os
import shutil
import socket
import subprocess
import sys
import time
import urllib.request
from collections.abc import Iterator
from pathlib import Path


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def start_prefect_server(
    home: Path, log: Path, env: dict[str, str] | None = None
) -> tuple[subprocess.Popen, str]:
    """``prefect server start`` on a free loopback port with its own PREFECT_HOME (SQLite there unless
    ``env`` names a database: ``PREFECT_API_DATABASE_CONNECTION_URL``); returns the process and its
    API URL once ``/api/health`` answers."""
    port = free_port()
    full = {
        **{k: v for k, v in os.environ.items() if not k.startswith("PREFECT_")},
        "PREFECT_HOME": str(home),
        "PREFECT_SERVER_ANALYTICS_ENABLED": "false",
        "PREFECT_UI_ENABLED": "false",
        **(env or {}),
    }
    prefect = Path(sys.executable).with_name("prefect")
    with open(log, "wb") as out:
        proc = subprocess.Popen(
            [str(prefect), "server", "start", "--host", "127.0.0.1", "--port", str(port), "--no-ui"],
            env=full,
            stdout=out,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
    url = f"http://127.0.0.1:{port}/api"
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(f"prefect server exited: {log.read_text()[-2000:]}")
        try:
            with urllib.request.urlopen(f"{url}/health", timeout=2) as res:
                if res.status == 200:
                    return proc, url
        except OSError:
            time.sleep(0.5)
    stop(proc)
    raise RuntimeError(f"prefect server did not answer within 120 s: {log.read_text()[-2000:]}")


def postgres_bin() -> Path | None:
    """The folder of ``initdb`` and ``pg_ctl`` (on PATH, else Debian's /usr/lib/postgresql/N/bin)."""
    found = shutil.which("pg_ctl")
    if found and shutil.which("initdb"):
        return Path(os.path.realpath(found)).parent
    for folder in sorted(glob.glob("/usr/lib/postgresql/*/bin"), reverse=True):
        if os.access(f"{folder}/pg_ctl", os.X_OK) and os.access(f"{folder}/initdb", os.X_OK):
            return Path(folder)
    return None


def postgres_missing() -> str | None:
    """Why a PostgreSQL cluster cannot be made here (None when it can)."""
    if postgres_bin() is None:
        return "PostgreSQL's initdb/pg_ctl not found: `apt-get install postgresql` (make postgresql)"
    if os.geteuid() == 0 and shutil.which("runuser") is None:
        return "running as root without runuser: initdb refuses root"
    if os.geteuid() == 0:
        try:
            import pwd

            pwd.getpwnam("postgres")
        except KeyError:
            return "running as root and there is no 'postgres' user to run initdb as"
    return None


@contextlib.contextmanager
def postgres_cluster(database: str = "prefect") -> Iterator[tuple[str, Path]]:
    """A PostgreSQL cluster in a new temporary folder on a free loopback port (trust auth, user
    ``dsnet``), with ``database`` created; yields its asyncpg URL
    (``postgresql+asyncpg://dsnet@127.0.0.1:P/DB``) and the server's log file, then stops it
    (``pg_ctl stop -m fast``) and removes the folder. As root the server runs as user ``postgres``
    (initdb refuses root), in a folder under /tmp that user can reach."""
    import tempfile

    bin_dir = postgres_bin()
    assert bin_dir is not None, postgres_missing()
    folder = Path(tempfile.mkdtemp(prefix="dsnet-pg-"))
    as_user: list[str] = []
    if os.geteuid() == 0:
        shutil.chown(folder, "postgres")
        as_user = ["runuser", "-u", "postgres", "--"]
    data, port, log = folder / "data", free_port(), folder / "server.log"

    def run(*args: str) -> None:
        res = subprocess.run([*as_user, *args], cwd=folder, capture_output=True, text=True, timeout=120)
        if res.returncode != 0:
            raise RuntimeError(f"{Path(args[0]).name} failed: {res.stdout[-1500:]}{res.stderr[-1500:]}")

    try:
        run(f"{bin_dir}/initdb", "-D", str(data), "-U", "dsnet", "--auth=trust", "-E", "UTF8", "--no-sync")
        options = f"-h 127.0.0.1 -p {port} -k {folder} -c fsync=off"
        run(f"{bin_dir}/pg_ctl", "-D", str(data), "-l", str(log), "-w", "-t", "60", "-o", options, "start")
        try:
            run(f"{bin_dir}/createdb", "-h", "127.0.0.1", "-p", str(port), "-U", "dsnet", database)
            yield f"postgresql+asyncpg://dsnet@127.0.0.1:{port}/{database}", log
        finally:
            run(f"{bin_dir}/pg_ctl", "-D", str(data), "-m", "fast", "-w", "-t", "60", "stop")
    finally:
        shutil.rmtree(folder, ignore_errors=True)
