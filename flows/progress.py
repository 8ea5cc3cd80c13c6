"""An in-process progress hook: flows report finished blocks, the CLI draws bars from them."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass


@dataclass(frozen=True)
class BlockEvent:
    """``done`` of ``total`` blocks of ``stage`` finished (over all sequences of the run)."""

    stage: str
    done: int
    total: int
    sequence: str = ""


_listeners: list[Callable[[BlockEvent], None]] = []


def add_listener(fn: Callable[[BlockEvent], None]) -> None:
    _listeners.append(fn)


def remove_listener(fn: Callable[[BlockEvent], None]) -> None:
    if fn in _listeners:
        _listeners.remove(fn)


def emit(event: BlockEvent) -> None:
    for fn in list(_listeners):
        fn(event)
