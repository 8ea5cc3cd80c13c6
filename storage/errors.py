"""Typed errors of the run store. Each names the store object and the problem."""

from __future__ import annotations


class StoreError(Exception):
    """A store object is missing, malformed, or does not match its contract."""

    def __init__(self, where: str, problem: str) -> None:
        self.where = where
        self.problem = problem
        super().__init__(f"{where}: {problem}")


class NoRunConfigError(StoreError):
    """The root holds no run config: not a run store (yet), or an unknown run id."""


class StoreFormatError(StoreError):
    """The store was written in another store format: relabel into a new run folder."""


class StoreAccessError(StoreError):
    """A remote store cannot be used: its endpoint does not answer, no credentials were found, the
    key is refused or the bucket does not exist. The message says what to check."""


class NotAFolderError(StoreError):
    """A store root (or a folder inside it) is a file: ``where`` names the file."""


class ContractError(StoreError):
    """An array or table does not match the stage's declared contract."""


class LockHeldError(StoreError):
    """Another live run holds the lock of a (sequence, stage)."""

    def __init__(self, where: str, holder: dict) -> None:
        self.holder = holder
        who = (
            f"host {holder.get('host')}, pid {holder.get('pid')}, run {holder.get('run_id')}, "
            f"since {holder.get('acquired')}"
        )
        super().__init__(where, f"locked by another run ({who}); wait for it or stop it")


class LockLostError(StoreError):
    """This run's lock was taken over (its heartbeat went stale); it must stop writing."""


class StoreWriteError(StoreError):
    """The store cannot be written: disk full, quota, read-only or permission denied. Retrying does
    not help; freeing space (or giving the run another place) and rerunning resumes the run."""


WRITE_ERRNOS = {
    28: "no space left on device",  # ENOSPC
    122: "disk quota exceeded",  # EDQUOT
    30: "read-only file system",  # EROFS
    13: "permission denied",  # EACCES
    1: "operation not permitted",  # EPERM
}


def as_write_error(exc: BaseException, where: str) -> StoreWriteError | None:
    """The :class:`StoreWriteError` an ``OSError`` of writing amounts to (None for other errors).

    Args:
        exc: the error raised while writing.
        where: the store object being written (its file when the error names none).
    """
    if not isinstance(exc, OSError) or exc.errno not in WRITE_ERRNOS:
        return None
    target = exc.filename or where
    return StoreWriteError(
        str(target),
        f"cannot write: {WRITE_ERRNOS[exc.errno]} (errno {exc.errno}); free space or fix the permissions "
        "(or label into another --run), then run the same command again to resume",
    )


class DamagedStoreError(StoreError):
    """A stored file is missing, truncated or does not match the checksum recorded when it was
    written. ``where`` names the file; the message says how to recompute it."""

    RERUN = "rerun `dsnet label` on it to recompute"

    def __init__(self, where: str, problem: str, fix: str = RERUN) -> None:
        super().__init__(where, f"{problem}; the store is damaged: {fix}")
        self.problem = problem
