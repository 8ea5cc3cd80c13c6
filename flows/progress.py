"""An in-process progress hook: flows report finished blocks (and, for blocks running in this
process, each finished item), the CLI draws bars from them."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass


@dataclass(frozen=True)
class BlockEvent:
    """``done`` of ``total`` items (frames or volumes, ``unit``) of ``stage`` are in finished blocks
    (over all sequences of the run); ``item=True``: one more item finished inside a running block."""

    stage: str
    done: int
    total: int
    sequence: str = ""
    unit: str = "frames"
    item: bool = False


_listeners: list[Callable[[BlockEvent], None]] = []


def add_listener(fn: Callable[[BlockEvent], None]) -> None:
    _listeners.append(fn)


def remove_listener(fn: Callable[[BlockEvent], None]) -> None:
    if fn in _listeners:
        _listeners.remove(fn)


def emit(event: BlockEvent) -> None:
    for fn in list(_listeners):
        fn(event)
