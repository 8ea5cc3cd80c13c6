"""Typed errors of the run store. Each names the store object and the problem."""

from __future__ import annotations


class StoreError(Exception):
    """A store object is missing, malformed, or does not match its contract."""

    def __init__(self, where: str, problem: str) -> None:
        self.where = where
        self.problem = problem
        super().__init__(f"{where}: {problem}")


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


class DamagedStoreError(StoreError):
    """A stored file is missing, truncated or does not match the checksum recorded when it was
    written. ``where`` names the file; the message says how to recompute it."""

    RERUN = "rerun `dsnet label` on it to recompute"

    def __init__(self, where: str, problem: str, fix: str = RERUN) -> None:
        super().__init__(where, f"{problem}; the store is damaged: {fix}")
        self.problem = problem
