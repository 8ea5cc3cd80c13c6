"""A seeded fuzzer of a finished run's inputs and store (used by ``tests/flows/test_fuzz.py``).

One reference is built once: a labelled tiny log (SemanticKITTI layout, one sequence of four
frames with poses, calib, times and labels), a seeded checkpoint (weights, card, shifting MLPs)
and a finished run of it (k = 2, dynamic shifting with few seeds, exported). Each case copies the
log, checkpoint and run, damages one file (truncate, flip one bit or delete), runs the commands
that read that file in-process (``dsnet label`` resuming the copied run, ``status``, ``export``,
``eval``) and classifies what happened:

acceptable
    ``error``        exit 2 and exactly one ``error:`` line naming the damaged file (or its folder)
    ``quarantined``  ``--on-error skip``: the frame is quarantined, its reason names the file, and
                     the run equals a fresh run of the damaged log
    ``recomputed``   the rerun exits 0 and its exported labels equal the reference's
    ``changed``      the damage is a valid different input (a flipped bit in a scan's floats, a
                     pose's digits): the rerun's labels equal a fresh run's on the damaged inputs

failures
    ``traceback``    a traceback in the output, or an exception that is not a typed exit
    ``unnamed``      an error that does not name the damaged file, or another exit code
    ``wrong``        exit 0 with labels that differ from what they should be, or ``status`` saying
                     done over data that does not read back as the reference
    ``hang``         a command ran past :data:`TIMEOUT_S`

Everything runs in this process through ``typer.testing.CliRunner`` on the session's Prefect
server (``PREFECT_API_URL`` must be set).
"""

from __future__ import annotations

import contextlib
import io
import json
import shutil
import signal
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from typer.testing import CliRunner

SEQ = "00"
FRAMES = 4
CLUSTERER = json.dumps({"kind": "dynamic_shift", "n_seeds": 20, "bandwidths": [0.2, 1.8, 3.4]})
TIMEOUT_S = 180
DAMAGES = ("truncate", "bitflip", "delete")
FAILURES = ("traceback", "unnamed", "wrong", "hang")

# target -> (group, glob relative to the group's root)
TARGETS: dict[str, tuple[str, str]] = {
    "scan": ("log", f"sequences/{SEQ}/velodyne/*.bin"),
    "label": ("log", f"sequences/{SEQ}/labels/*.label"),
    "poses": ("log", f"sequences/{SEQ}/poses.txt"),
    "calib": ("log", f"sequences/{SEQ}/calib.txt"),
    "times": ("log", f"sequences/{SEQ}/times.txt"),
    "model": ("ckpt", "model.safetensors"),
    "card": ("ckpt", "card.json"),
    "shift": ("ckpt", "shift.safetensors"),
    "manifest": ("run", f"sequences/{SEQ}/*/manifest.json"),
    "fragment": ("run", f"sequences/{SEQ}/*/blocks/*.json"),
    "item": ("run", f"sequences/{SEQ}/*/items/*.json"),
    "block_npz": ("run", f"sequences/{SEQ}/*/blocks/*.npz"),
    "chunk": ("run", f"sequences/{SEQ}/*/arrays.zarr/*/c/**/*"),
    "zarr_json": ("run", f"sequences/{SEQ}/*/arrays.zarr/**/zarr.json"),
    "parquet": ("run", "tables/**/*.parquet"),
    "run_json": ("run", "run.json"),
}


class Hang(BaseException):
    """A command ran past the timeout (a BaseException: nothing in the product catches it)."""


@dataclass(frozen=True)
class Reference:
    log: Path
    ckpt: Path
    run: Path
    labels: dict[str, bytes]  # exported predictions by file name


@dataclass
class Case:
    target: str
    damage: str
    seed: int
    file: str = ""
    outcome: str = ""
    detail: str = ""
    steps: list[str] = field(default_factory=list)


def invoke(*args) -> tuple[int, str, BaseException | None]:
    """Run ``dsnet ARGS`` in-process with a timeout: (exit code, output, untyped exception)."""
    from flows.cli import app

    def on_alarm(signum, frame):
        raise Hang(f"dsnet {args[0]} ran past {TIMEOUT_S} s")

    previous = signal.signal(signal.SIGALRM, on_alarm)
    signal.alarm(TIMEOUT_S)
    logs = io.StringIO()
    try:
        with _log_consoles_to(logs):
            res = CliRunner().invoke(app, [str(a) for a in args])
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)
    exc = res.exception if res.exception is not None and not isinstance(res.exception, SystemExit) else None
    return res.exit_code, res.output + logs.getvalue(), exc


@contextlib.contextmanager
def _log_consoles_to(stream):
    """Logging handlers that print through a rich console (Prefect's) keep the stream they were
    made with: in one process under CliRunner that is an earlier invocation's, closed, capture.
    Point them at ``stream`` for this invocation (what they print is part of the output)."""
    import logging

    loggers = [
        logging.getLogger(),
        *[v for v in logging.Logger.manager.loggerDict.values() if isinstance(v, logging.Logger)],
    ]
    saved = []
    for lg in loggers:
        for h in lg.handlers:
            console = getattr(h, "console", None)
            if console is not None and hasattr(console, "file"):
                saved.append((console, console.file))
                console.file = stream
    try:
        yield
    finally:
        for console, file in saved:
            console.file = file


def label_args(log: Path, run: Path, ckpt: Path, on_error: str = "fail") -> list:
    return [
        "label", log, "--run", run, "--scans", "2", "--checkpoint", ckpt, "--clusterer", CLUSTERER,
        "--block-size", "2", "--on-error", on_error,
    ]  # fmt: skip


def export_labels(run: Path, out: Path) -> tuple[int, str, BaseException | None, dict[str, bytes]]:
    code, output, exc = invoke("export", run, "--format", "semantickitti", "--out", out)
    preds = out / "sequences" / SEQ / "predictions"
    labels = {p.name: p.read_bytes() for p in sorted(preds.glob("*.label"))} if code == 0 else {}
    return code, output, exc, labels


def build_reference(base: Path) -> Reference:
    """The undamaged log, checkpoint and finished, exported run."""
    from tests.helpers.tiny_log import write_tiny_log
    from tests.model_helpers import make_checkpoint

    work = base / "case"
    log = write_tiny_log(work / "log", frames=FRAMES)
    ckpt = make_checkpoint(work / "ckpt", seed=0)
    run = work / "run"
    code, output, exc = invoke(*label_args(log, run, ckpt))
    assert code == 0 and exc is None, output[-3000:]
    code, output, exc, labels = export_labels(run, base / "export")
    assert code == 0 and len(labels) == FRAMES, output
    shutil.copytree(work, base / "case-pristine")
    return Reference(log, ckpt, run, labels)


def damage(path: Path, kind: str, rng: np.random.Generator) -> str:
    """Damage one file in place; returns what was done."""
    data = path.read_bytes()
    if kind == "delete":
        path.unlink()
        return "deleted"
    if kind == "truncate":
        keep = int(rng.integers(0, max(len(data), 1)))
        path.write_bytes(data[:keep])
        return f"truncated {len(data)} -> {keep} bytes"
    if not data:
        path.write_bytes(b"\x01")
        return "empty file got one byte"
    at, bit = int(rng.integers(0, len(data))), int(rng.integers(0, 8))
    buf = bytearray(data)
    buf[at] ^= 1 << bit
    path.write_bytes(bytes(buf))
    return f"flipped bit {bit} of byte {at}/{len(data)}"


def _candidates(root: Path, pattern: str) -> list[Path]:
    return sorted(p for p in root.glob(pattern) if p.is_file() and not p.name.startswith("."))


def _names_file(output: str, file: Path, root: Path) -> bool:
    """Exactly one ``error:`` line, naming the file or a folder of it inside ``root``."""
    text = " ".join(output.split())  # rich wraps long lines
    errors = [line for line in output.splitlines() if line.startswith("error: ")]
    if len(errors) != 1:
        return False
    inside = [p for p in file.parents if root in p.parents and len(p.relative_to(root).parts) >= 2]
    candidates = [file, file.parent, *inside]
    return any(str(c) in text for c in candidates)


def _names_file_anywhere(output: str, file: Path, root: Path) -> bool:
    text = " ".join(output.split())
    inside = [p for p in file.parents if root in p.parents and len(p.relative_to(root).parts) >= 2]
    return any(str(c) in text for c in [file, file.parent, *inside])


def _step(case: Case, name: str, code: int, output: str, exc, file: Path, root: Path) -> str:
    """Classify one command's ending: ok (exit 0), error (typed, named) or a failure."""
    case.steps.append(f"{name}:{code}")
    if exc is not None:
        if isinstance(exc, Hang):
            return "hang"
        case.detail = f"{name}: {type(exc).__name__}: {exc}"
        return "traceback"
    if "Traceback" in output:
        case.detail = f"{name}: traceback in output: {output[output.index('Traceback') :][:600]}"
        return "traceback"
    if code == 0:
        return "ok"
    if code == 2 and _names_file(output, file, root):
        return "error"
    if code == 1 and name == "label" and _names_file_anywhere(output, file, root):
        return "error"  # --on-error skip: the sequence's stage failed, named; the run went on
    if code == 2 and case.target == "manifest" and case.damage == "delete":
        stage = file.parent.name  # a lost manifest is a stage never run: naming the stage is all
        if f"'{stage}'" in output or f"/{stage}" in output:
            return "error"
    case.detail = f"{name}: exit {code}: {output[-600:]}"
    return "unnamed"


def _quarantined(run: Path) -> list[str]:
    from storage.run import RunStore
    from tasks.methods import get_pipeline

    with contextlib.suppress(Exception):
        rows = RunStore(run).read_table(SEQ, get_pipeline()["ingest"].table("frames")).to_pylist()
        return [str(r.get("reason")) for r in rows if r.get("status") == "quarantined"]
    return []


def _pristine(ref: Reference) -> Path:
    """Where the undamaged log, checkpoint and run are kept (at ``ref``'s paths: the case's)."""
    return ref.run.parent.parent / (ref.run.parent.name + "-pristine")


def run_case(ref: Reference, target: str, kind: str, seed: int, keep: Path | None = None) -> Case:
    """Restore the reference's log, checkpoint and run in place (the run records their paths),
    damage one file of ``target``, run the commands, classify; a failing case's folder is copied
    to ``keep``."""
    case = Case(target, kind, seed)
    rng = np.random.default_rng([seed, list(TARGETS).index(target), DAMAGES.index(kind)])
    work = ref.run.parent
    log, ckpt, run = ref.log, ref.ckpt, ref.run
    pristine = _pristine(ref)
    shutil.rmtree(work)
    for name in ("log", "ckpt", "run"):
        shutil.copytree(pristine / name, work / name)
    group, pattern = TARGETS[target]
    root = {"log": log, "ckpt": ckpt, "run": run}[group]
    files = _candidates(root, pattern)
    file = files[int(rng.integers(0, len(files)))]
    case.file = str(file.relative_to(work))
    case.detail = damage(file, kind, rng)
    try:
        if group == "log":
            case.outcome = _log_case(
                case, ref, log, ckpt, run, file, work, on_error=("fail", "skip")[seed % 2]
            )
        elif group == "ckpt":
            case.outcome = _ckpt_case(case, ref, log, ckpt, run, file, work)
        else:
            case.outcome = _store_case(case, ref, log, ckpt, run, file, work)
    except Hang as exc:
        case.outcome, case.detail = "hang", str(exc)
    if keep is not None and case.outcome in FAILURES:
        shutil.copytree(work, keep / f"{target}-{kind}-{seed}", dirs_exist_ok=True)
    return case


def _rerun_and_compare(
    case, ref, log, ckpt, run, file, work, expect: dict[str, bytes] | None, on_error="fail"
):
    """``label`` resuming ``run``; exit 0 must export ``expect`` (None: a fresh run's labels)."""
    code, out, exc = invoke(*label_args(log, run, ckpt, on_error))
    step = _step(case, "label", code, out, exc, file, work)
    if step != "ok":
        return step
    code, out, exc, labels = export_labels(run, work / "export")
    step = _step(case, "export", code, out, exc, file, work)
    if step != "ok":
        return "unnamed" if step == "error" else step  # label said done, export refuses
    if expect is None:  # a fresh run on the same (damaged) inputs is the oracle
        fresh = work / "fresh"
        fcode, fout, fexc = invoke(*label_args(log, fresh, ckpt, on_error))
        if _step(case, "fresh", fcode, fout, fexc, file, work) != "ok":
            case.detail = f"resumed run exited 0, a fresh run exit {fcode}: {fout[-400:]}"
            return "wrong"
        expect = export_labels(fresh, work / "fresh-export")[3]
    if labels != expect:
        differ = sorted(set(labels) ^ set(expect)) + [
            n for n in labels if n in expect and labels[n] != expect[n]
        ]
        case.detail = f"exported labels differ in {differ}"
        return "wrong"
    code, out, exc = invoke("status", run)
    step = _step(case, "status", code, out, exc, file, work)
    if step != "ok":
        return step
    reasons = _quarantined(run)
    if reasons:
        if not any(file.name in r for r in reasons):
            case.detail = f"quarantined without naming the file: {reasons}"
            return "unnamed"
        return "quarantined"
    return "recomputed" if labels == ref.labels else "changed"


def _log_case(case, ref, log, ckpt, run, file, work, on_error):
    outcome = _rerun_and_compare(case, ref, log, ckpt, run, file, work, None, on_error)
    if case.target == "label" and outcome not in FAILURES:
        code, out, exc = invoke(
            "eval", "--gt", log, "--pred", ref.run.parent.parent / "export", "--sequences", SEQ, "--json",
            work / "eval.json",
        )  # fmt: skip
        step = _step(case, "eval", code, out, exc, file, work)
        if step == "ok":
            frames = json.loads((work / "eval.json").read_text()).get("frames")
            present = len(list(file.parent.glob("*.label")))
            if case.damage == "truncate" or frames != present:
                case.detail = f"eval exit 0 over {case.detail}: {frames} frames scored, {present} gt files"
                return "wrong"
        elif step in FAILURES:
            return step
        elif outcome == "changed":
            outcome = "error"
    return outcome


def _ckpt_case(case, ref, log, ckpt, run, file, work):
    """A damaged checkpoint is never a valid different model: exit 0 must give the reference, in
    the resumed run (which may not need the weights again) and in a fresh one (which loads them)."""
    outcome = _rerun_and_compare(case, ref, log, ckpt, run, file, work, ref.labels)
    if outcome in FAILURES:
        return outcome
    shutil.rmtree(work / "export", ignore_errors=True)
    fresh = _rerun_and_compare(case, ref, log, ckpt, work / "fresh-ckpt", file, work, ref.labels)
    return fresh if fresh in FAILURES or outcome == "recomputed" else outcome


def _store_case(case, ref, log, ckpt, run, file, work):
    """``status`` and ``export`` on the damaged store, then ``label`` repairs it to the reference."""
    code, out, exc = invoke("status", run)
    step = _step(case, "status", code, out, exc, file, work)
    if step in FAILURES:
        return step
    says_done = step == "ok" and not any(w in out for w in ("damaged", "missing", "partial", "stale"))
    if says_done:  # the cheap check compares sizes: a flipped bit is for --verify to find
        code, out, exc = invoke("status", run, "--verify")
        step = _step(case, "status-verify", code, out, exc, file, work)
        if step in FAILURES:
            return step
        says_done = step == "ok" and not any(w in out for w in ("damaged", "missing", "partial", "stale"))
    code, out, exc, labels = export_labels(run, work / "export-damaged")
    step = _step(case, "export", code, out, exc, file, work)
    if step in FAILURES:
        return step
    if step == "ok" and labels != ref.labels:
        case.detail = f"export exit 0 with labels unlike the reference ({case.detail})"
        return "wrong"
    if says_done and not _tables_equal(run, _pristine(ref) / "run"):
        case.detail = f"status says done but the tables differ from the reference ({case.detail})"
        return "wrong"
    shutil.rmtree(work / "export", ignore_errors=True)
    outcome = _rerun_and_compare(case, ref, log, ckpt, run, file, work, ref.labels)
    if outcome not in FAILURES and outcome != "error" and not _tables_equal(run, _pristine(ref) / "run"):
        case.detail = f"label exit 0 but the tables differ from the reference ({case.detail})"
        return "wrong"
    return outcome


# what every run rewrites with its own times and id: not compared
_VOLATILE_TABLES = {"stage_timings"}
_VOLATILE_COLUMNS = {"run_id", "created"}


def _tables_equal(run: Path, ref: Path) -> bool:
    import pyarrow.parquet as pq

    for part in sorted(ref.glob("tables/**/*.parquet")):
        rel = part.relative_to(ref)
        if rel.parts[1] in _VOLATILE_TABLES:
            continue
        try:
            got = pq.read_table(run / rel, page_checksum_verification=True)
            want = pq.read_table(part)
            keep = [c for c in want.column_names if c not in _VOLATILE_COLUMNS]
            if got.column_names != want.column_names or not got.select(keep).equals(want.select(keep)):
                return False
        except Exception:  # any unreadable table is "not equal" here
            return False
    return True


def summarise(cases: list[Case]) -> str:
    """A counts table: target × damage → outcome counts, then the failures one per line."""
    counts = Counter((c.target, c.damage, c.outcome) for c in cases)
    outcomes = sorted({c.outcome for c in cases}, key=lambda o: (o in FAILURES, o))
    head = f"{'target':<10} {'damage':<9} " + " ".join(f"{o:>11}" for o in outcomes)
    lines = [head, "-" * len(head)]
    for target in TARGETS:
        for kind in DAMAGES:
            row = [counts[(target, kind, o)] for o in outcomes]
            if any(row):
                lines.append(f"{target:<10} {kind:<9} " + " ".join(f"{n:>11}" for n in row))
    total = Counter(c.outcome for c in cases)
    lines.append("-" * len(head))
    lines.append(f"{'total':<20} " + " ".join(f"{total[o]:>11}" for o in outcomes))
    for c in cases:
        if c.outcome in FAILURES:
            lines.append(f"FAIL {c.outcome}: {c.target}/{c.damage}/seed {c.seed} {c.file}: {c.detail[:500]}")
    return "\n".join(lines)
