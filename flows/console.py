"""What a person sees on the terminal while a command runs Prefect flows.

A failing flow makes Prefect log the whole traceback (~60 lines) before the command's own one-line
``error:``. :func:`hide_tracebacks` keeps Prefect's console lines but drops their tracebacks from
the terminal (the Prefect API's logs keep them); ``--debug`` leaves them on.
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
