"""What a person sees on the terminal while a command runs Prefect flows.

A failing flow makes Prefect log the whole traceback (~60 lines) before the command's own one-line
``error:``. :func:`hide_tracebacks` keeps Prefect's console lines but drops their tracebacks from
the terminal (the Prefect API's logs keep them), and drops the ERROR lines that only repeat a
typed error (a bad scan, a damaged store: ``DsnetError``, ``StoreError``) which the command then
prints once itself (``error: …``, or ``failed: sequence …`` in its summary); ``--debug`` leaves
them all on.
"""

from __future__ import annotations

import logging


class _WithoutTraceback(logging.Formatter):
    """Formats a record like ``inner`` but without its exception or stack text (the record itself is
    left as it was, for the other handlers)."""

    def __init__(self, inner: logging.Formatter | None) -> None:
        super().__init__()
        self.inner = inner or logging.Formatter()

    def format(self, record: logging.LogRecord) -> str:
        saved = record.exc_info, record.exc_text, record.stack_info
        record.exc_info = record.exc_text = record.stack_info = None
        try:
            return self.inner.format(record)
        finally:
            record.exc_info, record.exc_text, record.stack_info = saved


def _typed_errors() -> tuple[type, ...]:
    from dsnet_core.errors import DsnetError
    from storage.errors import StoreError

    return (DsnetError, StoreError)


def _subclass_names(classes: tuple[type, ...]) -> set[str]:
    names, todo = set(), list(classes)
    while todo:
        cls = todo.pop()
        if cls.__name__ not in names:
            names.add(cls.__name__)
            todo += cls.__subclasses__()
    return names


class _TypedErrorEcho(logging.Filter):
    """Drops an ERROR record that carries (or names) a typed project error: the command prints it."""

    def filter(self, record: logging.LogRecord) -> bool:
        if record.levelno < logging.ERROR:
            return True
        typed = _typed_errors()
        exc = record.exc_info[1] if record.exc_info else None
        args = record.args if isinstance(record.args, tuple) else ()
        if isinstance(exc, typed) or any(isinstance(a, typed) for a in args):
            return False
        text = record.getMessage()
        return not any(f"exception {n}:" in text or f": {n}(" in text for n in _subclass_names(typed))


def hide_tracebacks() -> None:
    """Wrap the formatter of every console handler Prefect configured (call after importing a flow:
    Prefect sets its logging up on import). Idempotent."""
    loggers = [logging.getLogger()] + [
        lg
        for name, lg in logging.root.manager.loggerDict.items()
        if name.startswith("prefect") and isinstance(lg, logging.Logger)
    ]
    for logger in loggers:
        for handler in logger.handlers:
            if isinstance(handler, logging.StreamHandler) and not isinstance(
                handler.formatter, _WithoutTraceback
            ):
                handler.setFormatter(_WithoutTraceback(handler.formatter))
                handler.addFilter(_TypedErrorEcho())
