"""Kill a running ``dsnet`` process at a chosen moment: after a delay, or when a chosen stage of a
run store has started (optionally after it finished some blocks), then SIGKILL (or another signal).

The trigger is read from outside, through the run store's manifests, as an operator would see it;
the process is one the harness started, and only it is signalled (its children, such as a
temporary Prefect server, are left to their own clean-up, as after a real ``kill -9``).
"""

from __future__ import annotations

import signal
import subprocess
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass


@dataclass(frozen=True)
class KillPoint:
    """When to signal.

    Attributes:
        stage: kill once this stage's manifest says ``running`` in ``sequence`` (None: time only).
        sequence: the sequence whose stage is watched.
        blocks: and once at least this many of its blocks are complete.
        delay_s: seconds to wait after the stage trigger (or after start, with no stage).
        sig: the signal (SIGKILL by default; SIGINT is Ctrl-C, SIGTERM a polite stop).
    """

    stage: str | None = None
    sequence: str = "00"
    blocks: int = 0
    delay_s: float = 0.0
    sig: int = signal.SIGKILL

    def describe(self) -> str:
        where = "start" if self.stage is None else f"{self.sequence}/{self.stage} ({self.blocks}+ blocks)"
        return f"{signal.Signals(self.sig).name} {self.delay_s:.2f}s after {where}"


@dataclass
class KillResult:
    """What happened: whether the signal was sent (the process may have finished first), the exit
    code, its output, and seconds from the signal to the process's exit."""

    killed: bool
    returncode: int
    output: str
    exit_after_s: float | None


def stage_started(root: str, sequence: str, stage: str, blocks: int = 0) -> Callable[[], bool]:
    """A condition: ``stage`` of ``sequence`` in run store ``root`` is running (or done) with at
    least ``blocks`` complete blocks."""
    from storage.run import RunStore

    store = RunStore(root)

    def cond() -> bool:
        try:
            m = store.read_manifest(sequence, stage)
        except Exception:
            return False
        if m is None or m.status not in ("running", "done"):
            return False
        return blocks <= 0 or len(store.completed_blocks(sequence, stage, m.fingerprint)) >= blocks

    return cond


def run_and_kill(
    cmd: list[str],
    env: dict[str, str],
    point: KillPoint,
    root: str | None = None,
    cwd: str | None = None,
    timeout: float = 600,
    poll_s: float = 0.02,
    when: Callable[[], bool] | None = None,
) -> KillResult:
    """Start ``cmd``, signal it at ``point`` (``root`` is the run store watched for a stage trigger),
    and wait for it to end. ``when`` is a trigger of the caller's own (e.g. a training checkpoint's
    epoch count), used instead of a stage trigger; ``point.delay_s`` counts from it.

    Returns:
        The result; ``killed`` is False when the process ended before the trigger.
    """
    cond = when
    if cond is None and point.stage is not None:
        if root is None:
            raise ValueError("a stage trigger needs the run store root")
        cond = stage_started(root, point.sequence, point.stage, point.blocks)
    out = subprocess.PIPE
    proc = subprocess.Popen(cmd, cwd=cwd, env=env, stdout=out, stderr=subprocess.STDOUT, text=True)
    chunks: list[str] = []
    reader = threading.Thread(target=lambda: chunks.append(proc.stdout.read() if proc.stdout else ""))
    reader.start()
    deadline = time.monotonic() + timeout
    killed, exit_after = False, None
    try:
        while cond is not None and not cond():
            if proc.poll() is not None or time.monotonic() > deadline:
                break
            time.sleep(poll_s)
        if proc.poll() is None and time.monotonic() <= deadline:
            end = time.monotonic() + point.delay_s
            while time.monotonic() < end and proc.poll() is None:
                time.sleep(min(poll_s, max(end - time.monotonic(), 0)))
            if proc.poll() is None:
                proc.send_signal(point.sig)
                killed, t0 = True, time.monotonic()
                proc.wait(timeout=max(deadline - time.monotonic(), 30))
                exit_after = time.monotonic() - t0
        proc.wait(timeout=max(deadline - time.monotonic(), 1))
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=30)
        reader.join(timeout=30)
    return KillResult(killed, proc.returncode, "".join(chunks), exit_after)


def where_stopped(root: str, sequences: list[str] | tuple[str, ...], stages: list[str] | tuple[str, ...]):
    """Where a stopped run stood, read from its run store: ``(stage, detail)``.

    ``stage`` is the first stage (in ``stages`` order) that some sequence has started but not
    finished, ``"before <stage>"`` when the previous stages are done and this one has no manifest
    yet, ``"startup"`` when no stage has started, and ``"publish"`` when every stage is done (the
    run was reporting). ``detail`` lists, per sequence, that stage's status and complete blocks.
    """
    from storage.run import RunStore

    store = RunStore(root)
    started_any = False
    for stage in stages:
        states = {}
        for seq in sequences:
            m = store.read_manifest(seq, stage)
            if m is None:
                states[seq] = "-"
            elif m.status == "done":
                states[seq] = "done"
            else:
                n = len(store.completed_blocks(seq, stage, m.fingerprint))
                states[seq] = f"{m.status} {n}/{len(m.blocks)}"
        if all(s == "done" for s in states.values()):
            started_any = True
            continue
        detail = ", ".join(f"{seq}: {s}" for seq, s in states.items())
        if all(s == "-" for s in states.values()):
            return (f"before {stage}" if started_any else "startup"), detail
        return stage, detail
    return "publish", ""


def kill_track_script(pipeline_factory: str, at_call: int = 4) -> str:
    """A ``python -c`` script that reruns the ``track`` stage of the store ``sys.argv[1]`` (run
    ``r1``) with the pipeline ``module:function`` names, SIGKILLing itself at the ``at_call``-th
    frame the tracker receives."""
    module, func = pipeline_factory.split(":")
    return f"""
import os, signal, sys
import dsnet_core.temporal.tracking as tr
_orig, _calls = tr.Tracker.add_detections, [0]
def add_detections(self, *args, **kw):
    _calls[0] += 1
    if _calls[0] == {at_call}:
        os.kill(os.getpid(), signal.SIGKILL)
    return _orig(self, *args, **kw)
tr.Tracker.add_detections = add_detections
from storage.run import RunStore
from tasks.run_config import read_run
from tasks.runner import run_stage_plain
from {module} import {func}
store = RunStore(sys.argv[1])
run_stage_plain(store, {func}(), "00", "track", read_run(store, "r1"), "r1", force=True)
"""


def kill_track_in_a_copy(store, pipeline_factory: str, root, frames: int = 6):
    """Copy run store ``store`` to ``root``, rerun its ``track`` stage in a subprocess that SIGKILLs
    itself at the fourth frame (:func:`kill_track_script`), check that exactly the first three frames
    are done, and return the copy (a :class:`~storage.run.RunStore`)."""
    import os
    import shutil
    import sys
    from pathlib import Path

    from storage.contract import StageContract
    from storage.run import RunStore
    from tasks.base import FRAME_LABEL

    repo = Path(__file__).resolve().parents[2]
    shutil.copytree(store.uri, root)
    res = subprocess.run(
        [sys.executable, "-c", kill_track_script(pipeline_factory), str(root)],
        cwd=repo, env={**os.environ, "PYTHONPATH": str(repo)}, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert res.returncode == -signal.SIGKILL, res.stderr
    copy = RunStore(root)
    done = copy.arrays("00", StageContract("track", "frame", (FRAME_LABEL,))).done().tolist()
    assert done == [True] * 3 + [False] * (frames - 3)
    return copy


KILL_AT_REPLACE = """
import os, signal, sys
target, at, trace = os.path.abspath(sys.argv[1]), sys.argv[2], sys.argv[3]
name, _, nth = at.rpartition(":") if ":" in at else ("", "", at)
_replace, _count = os.replace, {}
def replace(src, dst, *args, **kwargs):
    dst_abs = os.path.abspath(os.fspath(dst))
    if dst_abs.startswith(target + os.sep):
        rel = os.path.relpath(dst_abs, target)
        key = rel if name else ""
        if not name or rel == name:
            _count[key] = _count.get(key, 0) + 1
            if _count[key] == int(nth):
                os.kill(os.getpid(), signal.SIGKILL)
        if trace:
            with open(trace, "a") as f:
                f.write(rel + "\\n")
    return _replace(src, dst, *args, **kwargs)
os.replace = replace
sys.argv = ["dsnet", *sys.argv[4:]]
from flows.cli import main
main()
"""
"""A ``python -c`` script: ``dsnet ARGS…`` (``sys.argv[4:]``) that SIGKILLs itself just before a
chosen file lands in folder ``sys.argv[1]`` (every file there is written to a temporary name and
moved into place with ``os.replace``: each move is a commit point). ``sys.argv[2]`` is ``N`` (the
N-th move into the folder; 0 never kills) or ``REL:N`` (the N-th move onto path ``REL``, relative
to the folder); a non-empty ``sys.argv[3]`` is a file that records each landed path."""


def dsnet_killed_at_replace(
    folder, at: int | str, args: list, trace=None, timeout: float = 600
) -> subprocess.CompletedProcess:
    """Run ``dsnet ARGS…`` in a subprocess SIGKILLed before the ``at``-th file moved into ``folder``
    (or the ``N``-th move onto ``REL`` for ``at="REL:N"``: :data:`KILL_AT_REPLACE`); ``trace`` (a
    path) records the moves. Returns the finished process (return code ``-9`` when killed)."""
    import os
    import sys
    from pathlib import Path

    repo = Path(__file__).resolve().parents[2]
    env = {**os.environ, "PYTHONPATH": str(repo), "OMP_NUM_THREADS": "1"}
    cmd = [sys.executable, "-c", KILL_AT_REPLACE, str(folder), str(at), str(trace or ""), *map(str, args)]
    return subprocess.run(cmd, cwd=repo, env=env, capture_output=True, text=True, timeout=timeout)
