"""The services a run talks to, asked once before anything starts: the Prefect API at
``PREFECT_API_URL`` and a Dask scheduler at ``--dask-address``.

Left to themselves, Prefect's client fails a wrong URL with a 90-140-line traceback (``serve``
after saying it serves), and prefect-dask retries a refused scheduler for 30 s before a
117-line traceback. Each check here takes at most a few seconds and ends in one
:class:`~dsnet_core.errors.ServiceError` line naming the address and what to do.
"""

from __future__ import annotations

import os

TIMEOUT_S = 5.0


def check_services(dask_address: str | None = None) -> None:
    """Check the Prefect API at ``PREFECT_API_URL`` (when set) and the Dask scheduler at
    ``dask_address`` (when given). Raises :class:`~dsnet_core.errors.ServiceError`."""
    if os.environ.get("PREFECT_API_URL"):
        check_prefect_api(os.environ["PREFECT_API_URL"])
    if dask_address:
        check_dask_scheduler(dask_address)


def check_prefect_api(url: str, timeout_s: float = TIMEOUT_S) -> None:
    """Ask ``url``'s ``/health`` (what Prefect's own client asks) once, with a short timeout.

    Args:
        url: the API URL (``PREFECT_API_URL``, e.g. ``http://127.0.0.1:4200/api``).
        timeout_s: seconds to wait for the connection and for the answer.

    Raises:
        ServiceError: nothing answers there, or what answers is not a Prefect API.
    """
    import httpx

    from dsnet_core.errors import ServiceError

    headers = {}
    key = os.environ.get("PREFECT_API_KEY")
    if key:
        headers["Authorization"] = f"Bearer {key}"
    where = f"PREFECT_API_URL {url}"
    try:
        answer = httpx.get(url.rstrip("/") + "/health", headers=headers, timeout=timeout_s)
    except httpx.HTTPError as exc:
        raise ServiceError(
            f"{where}: no Prefect API answers ({type(exc).__name__}: {exc or 'no answer'}); start one "
            "(`prefect server start --host 127.0.0.1`) or unset PREFECT_API_URL to label with a "
            "temporary server"
        ) from None
    try:
        healthy = answer.status_code == 200 and answer.json() is True
    except ValueError:
        healthy = False
    if not healthy:
        hint = "" if url.rstrip("/").endswith("/api") else " (a Prefect server's API URL ends in /api)"
        raise ServiceError(
            f"{where}: not a Prefect API: GET /health answered {answer.status_code} "
            f"{answer.reason_phrase}, not true{hint}"
        )


def check_dask_scheduler(address: str, timeout_s: float = TIMEOUT_S) -> None:
    """Connect to ``address`` and shake hands as a Dask client does, within ``timeout_s``.

    Args:
        address: the scheduler's address (``tcp://host:port``; a bare ``host:port`` is TCP).
        timeout_s: seconds for the connection and for the handshake.

    Raises:
        ServiceError: not an address, nothing listens there, or what listens does not answer
            Dask's handshake.
    """
    import asyncio
    import socket
    from concurrent.futures import ThreadPoolExecutor

    from distributed.comm import connect
    from distributed.comm.addressing import get_address_host_port, parse_address
    from distributed.comm.registry import get_backend

    from dsnet_core.errors import ServiceError

    where = f"--dask-address {address}"
    try:
        scheme, _ = parse_address(address)
        get_backend(scheme)
        host, port = get_address_host_port(address) if scheme in ("tcp", "tls") else (None, None)
    except ValueError as exc:
        raise ServiceError(f"{where}: not a Dask address ({exc}); expected tcp://HOST:PORT") from None
    if host is not None:
        try:  # refused or unroutable: at once, where prefect-dask retries for 30 s
            socket.create_connection((host, port), timeout=timeout_s).close()
        except OSError as exc:
            raise ServiceError(
                f"{where}: no Dask scheduler answers ({exc.strerror or exc}); start one (`dask scheduler`, "
                "then `dask worker ADDRESS`) or label without --dask-address"
            ) from None

    async def handshake() -> None:
        comm = await asyncio.wait_for(connect(address, timeout=timeout_s), timeout_s)
        await comm.close()

    with ThreadPoolExecutor(1) as pool:  # its own thread and loop: the caller may be running one
        try:
            pool.submit(asyncio.run, handshake()).result()
        except (OSError, TimeoutError) as exc:
            raise ServiceError(
                f"{where}: something listens there but does not answer as a Dask scheduler "
                f"({type(exc).__name__}); check the address and port"
            ) from None
