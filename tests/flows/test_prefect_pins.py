"""The Prefect internals ``flows/server.py`` relies on, pinned: a Prefect upgrade that changes any of
them fails here, by name, instead of breaking ``dsnet label``'s temporary server at run time.

``flows/server.py`` (the one module that touches them):
- subclasses ``prefect.server.api.server.SubprocessASGIServer`` and overrides its private
  ``_run_uvicorn_command`` (to start the child with ``PR_SET_PDEATHSIG`` and its own session),
  constructing it with ``port=`` and using ``start(timeout=)``, ``stop()`` and ``api_url``;
- sets Prefect's private ``PREFECT__SERVER_EPHEMERAL`` / ``PREFECT__SERVER_FINAL`` variables the
  base class sets for its child, and starts ``prefect.server.api.server:create_app`` by factory;
- drains ``prefect.events.worker.EventsWorker`` with ``drain_all(timeout=, at_exit=)``.
"""

from __future__ import annotations

import inspect
from importlib.metadata import version


def test_prefect_is_the_pinned_minor():
    assert version("prefect").startswith("3.8."), version("prefect")


def test_the_subprocess_server_interface_we_subclass():
    from prefect.server.api import server

    base = server.SubprocessASGIServer
    assert callable(getattr(base, "_run_uvicorn_command", None))
    assert list(inspect.signature(base._run_uvicorn_command).parameters) == ["self"]
    assert "port" in inspect.signature(base.__init__).parameters
    assert "timeout" in inspect.signature(base.start).parameters
    assert callable(base.stop) and isinstance(base.__dict__.get("api_url"), property)
    assert callable(server.create_app)
    source = inspect.getsource(base._run_uvicorn_command)
    for private in ("PREFECT__SERVER_EPHEMERAL", "PREFECT__SERVER_FINAL", "create_app"):
        assert private in source, private  # what our override reproduces


def test_events_worker_drain_all_takes_timeout_and_at_exit():
    from prefect.events.worker import EventsWorker

    params = inspect.signature(EventsWorker.drain_all).parameters
    assert {"timeout", "at_exit"} <= set(params)


def test_our_server_overrides_exactly_that_method():
    from flows.server import _owned_server_class

    owned = _owned_server_class()
    assert "_run_uvicorn_command" in owned.__dict__
    assert owned.__mro__[1].__name__ == "SubprocessASGIServer"
