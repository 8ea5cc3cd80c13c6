"""Locks per (root, sequence, stage) with an owner and a heartbeat.

A lock is a small JSON object ``{host, pid, run_id, acquired, heartbeat}`` created exclusively
(``O_EXCL``-style link locally, a conditional PUT on S3). A second run polls until ``wait_s`` and
then raises :class:`LockHeldError` naming the holder. A lock is stale, and taken over, when its
owner is a dead process on this host or its heartbeat is older than ``stale_after_s`` (clocks of
different hosts are assumed to agree to well within that). Takeover deletes then re-creates
exclusively; if two runs take over the same stale lock at the same moment, the loser notices at
its next heartbeat or ownership check (:meth:`LockSet.check`) and stops with LockLostError.
"""

from __future__ import annotations

import json
import logging
import os
import socket
import threading
import time
from dataclasses import dataclass, field

from storage.errors import LockHeldError, LockLostError
from storage.fs import RootFS

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Owner:
    """Who holds a lock."""

    run_id: str
    host: str = field(default_factory=socket.gethostname)
    pid: int = field(default_factory=os.getpid)


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def is_stale(holder: dict, stale_after_s: float, now: float | None = None) -> bool:
    """True when the holder is a dead process on this host or its heartbeat is too old."""
    now = time.time() if now is None else now
    if holder.get("host") == socket.gethostname() and not _pid_alive(int(holder.get("pid", -1))):
        return True
    return now - float(holder.get("heartbeat", 0.0)) > stale_after_s


class Lock:
    """One lock file. Use through :class:`LockSet`."""

    def __init__(self, root: RootFS, rel: str, owner: Owner, stale_after_s: float) -> None:
        self.root = root
        self.rel = rel
        self.owner = owner
        self.stale_after_s = stale_after_s
        self.acquired_at: float | None = None

    def _content(self) -> bytes:
        now = time.time()
        return json.dumps(
            {
                "host": self.owner.host,
                "pid": self.owner.pid,
                "run_id": self.owner.run_id,
                "acquired": self.acquired_at or now,
                "heartbeat": now,
            }
        ).encode()

    def try_acquire(self) -> dict | None:
        """Acquire if free or stale. Returns None on success, else the holder's record."""
        for _ in range(3):
            self.acquired_at = time.time()
            if self.root.create_exclusive(self.rel, self._content()):
                return None
            holder = self.root.read_json(self.rel)
            if holder is None:
                continue  # released in between: try again
            if holder.get("run_id") == self.owner.run_id:
                return None  # re-entrant within one run
            if not is_stale(holder, self.stale_after_s):
                self.acquired_at = None
                return holder
            log.warning("taking over stale lock %s held by %s", self.root.url(self.rel), holder)
            self.root.remove(self.rel)
        return self.root.read_json(self.rel) or {}

    def owned(self) -> bool:
        holder = self.root.read_json(self.rel)
        return holder is not None and holder.get("run_id") == self.owner.run_id

    def beat(self) -> bool:
        """Refresh the heartbeat. Returns False if the lock is no longer ours."""
        if not self.owned():
            return False
        self.root.write_bytes(self.rel, self._content())
        return True

    def release(self) -> None:
        if self.owned():
            self.root.remove(self.rel)
        self.acquired_at = None


class LockSet:
    """The locks a run holds, acquired in a fixed order, kept alive by one heartbeat thread.

    Args:
        root: the store root.
        owner: this run.
        wait_s: how long to wait for a held lock before raising LockHeldError.
        stale_after_s: heartbeat age after which a lock counts as abandoned.
        heartbeat_s: refresh period (must be well below ``stale_after_s``).
    """

    def __init__(
        self,
        root: RootFS,
        owner: Owner,
        wait_s: float = 0.0,
        stale_after_s: float = 60.0,
        heartbeat_s: float = 5.0,
        poll_s: float = 0.2,
    ) -> None:
        self.root = root
        self.owner = owner
        self.wait_s = wait_s
        self.stale_after_s = stale_after_s
        self.heartbeat_s = heartbeat_s
        self.poll_s = poll_s
        self.held: dict[str, Lock] = {}
        self.lost: set[str] = set()
        self._mutex = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def acquire(self, rel: str) -> None:
        """Acquire one lock, waiting up to ``wait_s``. Raises LockHeldError naming the holder."""
        lock = Lock(self.root, rel, self.owner, self.stale_after_s)
        deadline = time.monotonic() + self.wait_s
        while True:
            holder = lock.try_acquire()
            if holder is None:
                break
            if time.monotonic() >= deadline:
                raise LockHeldError(self.root.url(rel), holder)
            time.sleep(self.poll_s)
        with self._mutex:
            self.held[rel] = lock
        self._ensure_thread()

    def release(self, rel: str) -> None:
        with self._mutex:
            lock = self.held.pop(rel, None)
        if lock is not None:
            lock.release()

    def release_all(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=self.heartbeat_s + 1)
        for rel in list(self.held):
            self.release(rel)

    def check(self, rel: str) -> None:
        """Raise LockLostError unless this run still owns ``rel``."""
        if rel in self.lost or rel not in self.held:
            raise LockLostError(self.root.url(rel), "this run's lock was taken over by another run")
        check_owner(self.root, rel, self.owner.run_id, missing_ok=False)

    def _ensure_thread(self) -> None:
        if self._thread is None or not self._thread.is_alive():
            self._stop.clear()
            self._thread = threading.Thread(target=self._beat_loop, name="dsnet-lock-heartbeat", daemon=True)
            self._thread.start()

    def _beat_loop(self) -> None:
        while not self._stop.wait(self.heartbeat_s):
            with self._mutex:
                locks = list(self.held.items())
            for rel, lock in locks:
                try:
                    if not lock.beat():
                        log.error("lock %s was taken over by another run", rel)
                        self.lost.add(rel)
                except OSError as exc:  # transient storage error: try again next beat
                    log.warning("heartbeat of %s failed: %s", rel, exc)


def check_owner(root: RootFS, rel: str, run_id: str, missing_ok: bool = True) -> None:
    """Raise LockLostError when the lock ``rel`` is held by a run other than ``run_id``.

    Args:
        missing_ok: a missing lock file passes (stages run without locks by tests and benchmarks);
            otherwise it counts as lost.
    """
    holder = root.read_json(rel)
    if holder is None:
        if missing_ok:
            return
        raise LockLostError(root.url(rel), "this run's lock was taken over by another run")
    if holder.get("run_id") != run_id:
        raise LockLostError(root.url(rel), f"taken over by run {holder.get('run_id')}; not writing")
