"""The README's production recipe, end to end on loopback: a ``prefect server start`` on a
PostgreSQL database (asyncpg), a Dask scheduler with two workers, an S3 run store; ``dsnet label``
a two-sequence log at k = 2 through every stage with ``--dask-address``. The run completes, the
labels equal a single-process run's, the flow and task runs are in PostgreSQL, and neither the
server nor the database logged an error.

The test makes its own PostgreSQL cluster (``initdb``/``pg_ctl`` in a temporary folder: a
session's processes end with it) and is skipped, saying why, where Debian's ``postgresql`` is not
installed (``make postgresql``)."""

from __future__ import annotations

import os
import subprocess
import uuid

import pytest

from storage.run import RunStore
from tests.flows import test_dask_cluster as reference
from tests.flows.conftest import REPO
from tests.helpers.cluster import start_cluster
from tests.helpers.services import postgres_cluster, postgres_missing, start_prefect_server, stop

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(postgres_missing() is not None, reason=str(postgres_missing())),
]
ckpt = reference.ckpt  # the tiny checkpoint and the single-process run's labels (module fixtures)
single_process = reference.single_process
STAGES = ("ingest", "align", "infer", "shift", "fuse", "stitch", "score")


def test_a_prefect_server_on_postgresql_two_dask_workers_and_s3(
    s3_endpoint,
    synth_log,
    ckpt,
    single_process,
    tmp_path,
):
    with postgres_cluster() as (database, pg_log):
        server, api = start_prefect_server(
            tmp_path / "prefect-home",
            tmp_path / "server.log",
            {"PREFECT_API_DATABASE_CONNECTION_URL": database},
        )
        env = {
            **os.environ, **s3_endpoint, "PYTHONPATH": str(REPO), "PREFECT_API_URL": api,
            "PREFECT_HOME": str(tmp_path / "client-home"),
        }  # fmt: skip
        cluster = start_cluster(tmp_path / "dask", env, n_workers=2)
        try:
            run = f"s3://dsnet-test/prod-{uuid.uuid4().hex[:8]}"
            res = subprocess.run(
                reference._label(env, synth_log, run, ckpt, "--dask-address", cluster.address),
                cwd=REPO, env=env, capture_output=True, text=True, timeout=900,
            )  # fmt: skip
            assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
            store = RunStore(run)
            for seq in ("00", "01"):
                assert [store.read_manifest(seq, s).status for s in STAGES] == ["done"] * len(STAGES)
            assert reference._export(env, run, tmp_path / "out") == single_process
            flows, tasks = _runs_in_postgres(database)
            assert flows.get("COMPLETED", 0) >= 1 and not set(flows) - {"COMPLETED"}, flows
            assert tasks.get("COMPLETED", 0) >= 2 * len(STAGES) and not set(tasks) - {"COMPLETED"}, tasks
        finally:
            cluster.stop()
            stop(server)
        server_log = (tmp_path / "server.log").read_text(errors="replace")
        database_log = pg_log.read_text(errors="replace")
    for bad in ("ERROR", "Traceback", "sqlalchemy.exc", "asyncpg.exceptions"):
        assert bad not in server_log, server_log[-4000:]
    errors = [line for line in database_log.splitlines() if " ERROR: " in line or " FATAL: " in line]
    assert not [e for e in errors if _PREFECT_RACE not in e], database_log[-4000:]


# Prefect's server inserts a task run from the client's call and from its task-run events; the
# loser of that race gets a primary-key violation, which the server's event recorder absorbs (its
# log above stays free of errors and every task run ends COMPLETED in the database), but
# PostgreSQL still logs the refused INSERT (PrefectHQ/prefect#21807, #21809).
_PREFECT_RACE = 'duplicate key value violates unique constraint "pk_task_run"'


def _runs_in_postgres(url: str) -> tuple[dict[str, int], dict[str, int]]:
    """Flow-run and task-run counts by state type, read from the database itself."""
    import asyncio

    import asyncpg

    async def counts() -> tuple[dict[str, int], dict[str, int]]:
        conn = await asyncpg.connect(url.replace("postgresql+asyncpg://", "postgresql://"))
        try:
            out = []
            for table in ("flow_run", "task_run"):
                rows = await conn.fetch(f"SELECT state_type, count(*) AS n FROM {table} GROUP BY state_type")
                out.append({str(r["state_type"]): int(r["n"]) for r in rows})
            return out[0], out[1]
        finally:
            await conn.close()

    return asyncio.run(counts())
