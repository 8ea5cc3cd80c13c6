"""The output folder of ``train``, ``adapt`` and ``import-checkpoint``: checked, then held.

:func:`writing_folder` refuses an ``--out`` that is a file (or lies under one) before any work,
then takes the run store's kind of lock (:mod:`storage.locks`: an owner record with host, pid and
a heartbeat, created exclusively) on the folder, so a second writer stops at once with one line
naming the first. A lock left by a killed writer (dead pid on this host, or a heartbeat older than
a minute) is taken over, so ``--resume`` after a SIGKILL works. Under ``torchrun`` only rank 0
holds it (the other ranks never write the folder).
"""

from __future__ import annotations

import contextlib
import os
import time
import uuid
from collections.abc import Iterator
from pathlib import Path

from dsnet_core.errors import ConfigError

LOCK = ".dsnet-writer.lock"
"""The lock file inside a model folder (hidden: checkpoints' readers never see it)."""


class FolderBusyError(ConfigError):
    """Another live ``dsnet`` command is writing the output folder."""


@contextlib.contextmanager
def writing_folder(out: Path, command: str, *, stale_after_s: float = 60.0) -> Iterator[None]:
    """Hold ``out`` for ``command`` (e.g. ``"dsnet train dsnet"``) while the body runs.

    Raises:
        OutputPathError: ``out`` is a file or lies under one (before anything is created).
        FolderBusyError: another live command holds the folder, naming it, its pid and host.
    """
    from flows.commands.common import check_output
    from storage.errors import LockHeldError
    from storage.fs import RootFS
    from storage.locks import LockSet, Owner

    check_output(out, "--out", "folder")
    if int(os.environ.get("RANK", "0")) != 0:
        yield
        return
    out = Path(out).expanduser().absolute()
    created = not out.exists()
    out.mkdir(parents=True, exist_ok=True)
    locks = LockSet(RootFS(out), Owner(f"{command} {uuid.uuid4().hex[:8]}"), stale_after_s=stale_after_s)
    try:
        locks.acquire(LOCK)
    except LockHeldError as exc:
        raise FolderBusyError(busy_line(out, exc.holder)) from None
    try:
        yield
    finally:
        locks.release_all()
        if created and not any(out.iterdir()):
            out.rmdir()  # a command that failed before writing leaves no empty folder behind


@contextlib.contextmanager
def interrupted_exit() -> Iterator[None]:
    """Ctrl-C (or SIGTERM) during ``train`` or ``adapt``: one line and exit code 130. The folder's
    lock is released on the way out (the ``with`` blocks unwind), every committed epoch and labelled
    round is kept, and ``--resume`` continues exactly where the run stopped."""
    import signal
    import threading

    import typer

    main = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGTERM, signal.default_int_handler) if main else None
    try:
        yield
    except KeyboardInterrupt:
        typer.secho(
            "error: interrupted; the finished epochs are kept: run the same command with --resume to "
            "continue",
            fg=typer.colors.RED,
            err=True,
        )
        raise typer.Exit(code=130) from None
    finally:
        if main:
            signal.signal(signal.SIGTERM, previous)


def busy_line(out: Path, holder: dict) -> str:
    """``OUT: being written by `dsnet train dsnet` (pid 123 on host h, since 21:30:02 UTC); …``."""
    command = str(holder.get("run_id", "another command")).rsplit(" ", 1)[0]
    since = time.strftime("%H:%M:%S UTC", time.gmtime(float(holder.get("acquired", 0.0))))
    return (
        f"{out}: being written by `{command}` (pid {holder.get('pid')} on host {holder.get('host')}, "
        f"since {since}); wait for it to finish or stop it, or choose another --out"
    )


IMPORT_FILES = frozenset({"card.json", "model.safetensors", "shift.safetensors"})
"""What ``import-checkpoint`` writes (a killed import may leave its weights without their card, and
a ``NAME.tmp`` it was writing)."""


def check_import_target(out: Path) -> str | None:
    """What ``import-checkpoint`` may write over: nothing but an earlier import, which it replaces
    whole (weights, shifting weights, card).

    Returns:
        None for a new or empty folder; for an earlier import, the line saying what is replaced.

    Raises:
        ConfigError: ``out`` holds a trained or adapted checkpoint (its weights, card and train state
            would be mixed with the import's), or any other model card.
    """
    from dsnet_core.model.card import CARD, card_json
    from dsnet_core.train.commit import PENDING

    out = Path(out)
    if not (out / CARD).is_file():
        if (out / PENDING).exists():
            raise ConfigError(f"{out} holds a training run's unfinished epoch: import into another --out")
        others = sorted(
            p.name for p in out.iterdir()
            if not p.name.startswith(".") and p.name.removesuffix(".tmp") not in IMPORT_FILES
        ) if out.is_dir() else []  # fmt: skip
        if others:  # a training or adaptation folder whose card was lost: not an earlier import
            raise ConfigError(
                f"{out} holds {', '.join(others[:4])}{' …' if len(others) > 4 else ''} but no model card: "
                "not an earlier import (importing would leave them beside the import's files); import "
                "into another --out"
            )
        return None
    data = card_json(out).get("training_data") or {}
    imported = data.get("imported")
    if imported is None:
        what = "a trained checkpoint (dsnet train)"
        if "adapt" in data:
            what = "an adapted checkpoint (dsnet adapt)"
        raise ConfigError(
            f"{out} holds {what}: importing would replace its weights and card and leave its training "
            "state; import into another --out"
        )
    return f"replaced the earlier import in {out.resolve()} (of {imported.get('source_file')})"
