"""Damage to the three kinds of model folder (issue 40, "Also"): a finished ``train`` folder, a
finished ``adapt`` folder and an ``import-checkpoint`` folder, each file of it truncated, bit-flipped
or deleted, then the commands that read such a folder run over it in-process:

- ``resume``: ``dsnet train dsnet … --resume`` (train, import) or ``dsnet adapt … --resume`` (adapt),
  asked for one more epoch (train: a second shift epoch) or round (adapt), which an uninterrupted run
  of the longer schedule ends with bit for bit;
- ``label``: ``dsnet label LOG --checkpoint CK`` up to the moment its server would start (the run
  itself is not started: :func:`run_case` stops it there), then what its infer stage loads;
- ``import``: ``dsnet import-checkpoint FILE --out CK``.

Each case's outcome (:data:`OUTCOMES`): a typed refusal in one ``error:`` line naming the damaged
file (for ``import``, the folder it refuses to write over), or a run whose result is exactly the
undamaged folder's (``ok``: the damaged file was not needed, or it was repaired). Failures: a
traceback, a refusal naming neither, an exit 0 with other tensors than expected (a silent mix), a
label whose infer stage would refuse only after its server started.
"""

from __future__ import annotations

import random
import shutil
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import torch
from typer.testing import CliRunner

DAMAGES = ("truncate", "flip", "delete")
OUTCOMES = ("refused", "ok", "card-edit", "traceback", "unnamed", "silent", "late")
FAILURES = ("traceback", "unnamed", "silent", "late")
TRAIN = ("--grid", "24,32,8", "--threads", "1", "--lr", "0.01", "--no-augment")
SCHEDULES = {
    "train": ("all", "semantic=1,offset=1,shift=1", "semantic=1,offset=1,shift=2"),
    "train1": ("semantic", "semantic=1", "semantic=2"),
}
"""The two training folders: ``--stage``, the finished epochs, the longer schedule a resume runs.
``train`` holds shifting weights; ``train1`` resumes an optimiser stage (its train state is read)."""
KINDS = ("train", "train1", "adapt", "import")


@dataclass
class Reference:
    """The undamaged folders and what each command over them ends with.

    Attributes:
        log: the tiny labelled log the training used (and ``label`` reads).
        folders: :data:`KINDS`: the finished folders to damage.
        longer: ``train``, ``train1``, ``adapt``: an uninterrupted run of one more epoch / round (a
            resume's result).
        released: the released file the import read.
        adapt_inputs: the adaptation's target, parent, corrections and source log.
    """

    log: Path
    folders: dict[str, Path]
    longer: dict[str, Path]
    released: Path
    adapt_inputs: dict[str, Path]


@dataclass
class Case:
    kind: str
    file: str
    damage: str
    command: str
    outcome: str
    detail: str


def invoke(*args) -> tuple[int, str, BaseException | None]:
    import logging

    from flows.cli import app

    logging.root.handlers.clear()  # the commands' basicConfig binds the runner's stream of the moment
    res = CliRunner().invoke(app, [str(a) for a in args])
    exc = res.exception if res.exception is not None and not isinstance(res.exception, SystemExit) else None
    return res.exit_code, res.output, exc


def train_args(log: Path, out: Path, kind: str, longer: bool = False) -> list:
    stage, trained, more = SCHEDULES[kind]
    epochs = more if longer else trained
    return ["train", "dsnet", log, "--out", out, "--stage", stage, "--epochs", epochs, *TRAIN]


def adapt_args(inputs: dict, out: Path, rounds: int) -> list:
    from tests.flows.test_adapt_cli import FAST_SHIFT

    return [
        "adapt", inputs["target"], "--out", out, "--from", inputs["parent"], "--labels", inputs["fixes"],
        "--source-log", inputs["source"], "--rounds", rounds, "--steps", "2", "--epochs", "1",
        "--clusterer", FAST_SHIFT, "--lr", "0.01", "--threads", "1",
    ]  # fmt: skip


def build_reference(base: Path) -> Reference:
    """Train, adapt and import the three folders, and the two longer runs (in-process)."""
    from tests.dsnet_core.model.reference_net import DSNetReference, randomize, spconv1_state
    from tests.flows.test_adapt_cli import corrections, unlabelled
    from tests.helpers.tiny_log import write_tiny_log
    from tests.model_helpers import make_checkpoint

    log = write_tiny_log(base / "log", frames=2)
    labelled = write_tiny_log(base / "labelled", frames=3, n=1000)
    inputs = {
        "fixes": corrections(labelled, base / "fixes", ["000001"]),
        "target": unlabelled(write_tiny_log(base / "target", frames=3, n=1000)),
        "source": write_tiny_log(base / "source", frames=2, n=1000, seed=1),
        "parent": make_checkpoint(base / "parent", seed=3),
    }
    released = base / "dsnet.pth"
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    torch.save(
        {"epoch": 1, "model_state": spconv1_state(randomize(DSNetReference(4)).state_dict())}, released
    )
    torch.set_num_threads(before)
    folders = {k: base / "folders" / k for k in KINDS}
    longer = {k: base / "longer" / k for k in ("train", "train1", "adapt")}
    runs = [
        *(train_args(log, folders[k], k) for k in SCHEDULES),
        *(train_args(log, longer[k], k, longer=True) for k in SCHEDULES),
        adapt_args(inputs, folders["adapt"], 1),
        adapt_args(inputs, longer["adapt"], 2),
        ["import-checkpoint", released, "--out", folders["import"], "--kind", "dsnet"],
    ]
    for args in runs:
        code, text, exc = invoke(*args)
        assert code == 0 and exc is None, f"{args}: {text[-3000:]}"
    return Reference(log, folders, longer, released, inputs)


def folder_files(folder: Path) -> list[str]:
    """The files of a folder that a case damages: every file but hidden ones (the lock, a staging
    folder) and the adaptation's run stores (``store/``: the store fuzz's, ``test_fuzz.py``)."""
    names = []
    for p in sorted(folder.rglob("*")):
        rel = p.relative_to(folder)
        if p.is_file() and rel.parts[0] != "store" and not any(part.startswith(".") for part in rel.parts):
            names.append(str(rel))
    return names


def damage(file: Path, kind: str, rng: random.Random) -> None:
    data = bytearray(file.read_bytes())
    if kind == "delete":
        file.unlink()
    elif kind == "truncate":
        file.write_bytes(bytes(data[: rng.randrange(len(data))]))
    else:
        i = rng.randrange(len(data))
        data[i] ^= 1 << rng.randrange(8)
        file.write_bytes(bytes(data))


def loaded(folder: Path) -> tuple[dict, dict]:
    """What the infer stage runs: the network's and the shifting MLPs' tensors."""
    from dsnet_core.model.bundle import load_shift_weights
    from dsnet_core.model.checkpoint import load_checkpoint

    model, _ = load_checkpoint(folder)
    return {k: v.clone() for k, v in model.state_dict().items()}, load_shift_weights(folder) or {}


def same(a: tuple[dict, dict], b: tuple[dict, dict]) -> bool:
    return all(
        x.keys() == y.keys() and all(torch.equal(x[k], y[k]) for k in x) for x, y in zip(a, b, strict=True)
    )


class _WouldStart(Exception):
    """Raised where ``dsnet label`` would start its server: every check before it passed."""


def _label(ref: Reference, ck: Path, run: Path) -> tuple[int, str, BaseException | None]:
    import flows.commands.label as label_command

    def stop(*_args, **_kwargs):
        raise _WouldStart

    original, label_command.run_label = label_command.run_label, stop
    try:
        return invoke("label", ref.log, "--run", run, "--scans", "1", "--checkpoint", ck)
    finally:
        label_command.run_label = original


def run_case(ref: Reference, kind: str, file: str, how: str, command: str, seed: int, work: Path) -> Case:
    """Damage ``file`` of a copy of ``kind``'s folder, run ``command`` over it, classify."""
    ck = work / "ck"
    for old in (ck, work / "run"):
        if old.exists():
            shutil.rmtree(old)
    shutil.copytree(ref.folders[kind], ck)
    damage(ck / file, how, random.Random(f"{kind}/{file}/{how}/{seed}"))
    expected = ref.folders[kind]
    if command == "resume" and kind == "adapt":
        code, text, exc = invoke(*adapt_args(ref.adapt_inputs, ck, 2), "--resume")
        expected = ref.longer["adapt"]
    elif command == "resume":
        code, text, exc = invoke(
            *train_args(ref.log, ck, kind if kind in SCHEDULES else "train", True), "--resume"
        )
        expected = ref.longer.get(kind, ref.folders[kind])
    elif command == "label":
        code, text, exc = _label(ref, ck, work / "run")
        if isinstance(exc, _WouldStart):
            try:
                result = loaded(ck)
            except Exception as err:  # any failure here is the infer stage's, after the server
                return Case(kind, file, how, command, "late", f"{type(err).__name__}: {err}")
            if not same(result, loaded(expected)):
                return Case(kind, file, how, command, "silent", "preflight passed, other tensors")
            return _card_checked(Case(kind, file, how, command, "ok", "preflight passed"), ck, expected)
    else:
        code, text, exc = invoke("import-checkpoint", ref.released, "--out", ck, "--kind", "dsnet")
        expected = ref.folders["import"]
    return classify(kind, file, how, command, code, text, exc, ck, expected)


def classify(kind, file, how, command, code, text, exc, ck: Path, expected: Path) -> Case:
    if exc is not None or "Traceback" in text:
        return Case(kind, file, how, command, "traceback", f"{type(exc).__name__}: {exc}")
    errors = [ln for ln in text.splitlines() if ln.startswith("error:")]
    if code != 0:
        named = len(errors) == 1 and (
            str(ck / file) in errors[0]
            or (file.endswith("train_state.safetensors") and str(ck / "train_state.json") in errors[0])
            or (command == "import" and f"{ck} holds" in errors[0])
            or (command == "resume" and f"{ck} is an imported checkpoint" in errors[0])
        )
        return Case(kind, file, how, command, "refused" if named else "unnamed", (errors or [text])[-1][:300])
    try:
        ok = same(loaded(ck), loaded(expected))
    except Exception as err:  # exit 0 over a folder that does not load
        return Case(kind, file, how, command, "silent", f"exit 0, then {type(err).__name__}: {err}")
    if not ok:
        return Case(kind, file, how, command, "silent", "exit 0, other tensors")
    left = sorted(set(folder_files(ck)) - set(folder_files(expected)))
    if left:  # e.g. an import over a training folder that kept its train state
        return Case(kind, file, how, command, "silent", f"exit 0, leaving {', '.join(left)}")
    return _card_checked(Case(kind, file, how, command, "ok", "exit 0"), ck, expected)


def _card_checked(case: Case, ck: Path, expected: Path) -> Case:
    """``ok`` only when the card reads as the expected one's; a bit flip that leaves valid JSON with
    another value of a field nothing checks (a metric, a description) is ``card-edit``."""
    import json

    def fields(folder: Path) -> dict:  # the folder's own path, as the expected folder's
        card = json.loads((folder / "card.json").read_text().replace(str(folder), str(expected)))
        card.pop("card_sha256", None)  # the card's digest of itself: it covers the seconds and the path
        card["metrics"] = [{k: v for k, v in m.items() if k != "seconds"} for m in card.get("metrics", [])]
        for r in (card.get("training_data") or {}).get("adapt", {}).get("rounds", []):
            r.pop("teacher_digest", None)  # a digest of the teacher's card: it holds the epochs' seconds
        return card

    got, want = fields(ck), fields(expected)
    changed = sorted(k for k in set(got) | set(want) if got.get(k) != want.get(k) and k != "code_version")
    if changed and case.command != "import":
        case.outcome, case.detail = "card-edit", f"card fields {changed} differ, accepted"
    return case


def summarise(cases: list[Case]) -> str:
    counts = Counter(c.outcome for c in cases)
    lines = [f"{len(cases)} cases: " + ", ".join(f"{counts[o]} {o}" for o in OUTCOMES if counts[o])]
    for c in cases:
        lines.append(f"{c.outcome:9} {c.kind:6} {c.file:28} {c.damage:8} {c.command:6} {c.detail[:160]}")
    return "\n".join(lines)
