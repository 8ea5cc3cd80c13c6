"""Names the store turns into path segments (sequences, partition values): plain names only, so a
name can never lead a path out of its folder (``--sequences ../../log/sequences/00`` once wrote stage
folders into the input log)."""

from __future__ import annotations

from storage.errors import StoreError


def check_plain_name(name: str, what: str = "sequence name") -> str:
    """Return ``name`` when it is one plain path segment.

    Raises:
        StoreError: empty, ``.``/``..``, or holding ``/``, ``\\`` or a NUL byte.
    """
    if not isinstance(name, str) or name in ("", ".", "..") or any(c in name for c in "/\\\0"):
        raise StoreError(
            repr(name),
            f"not a plain {what}: one folder name, without '/', '\\' or '..' (a sequence of the log)",
        )
    return name
