"""What a ``--resume`` may continue: the settings and data a checkpoint folder was trained with.

``dsnet train METHOD DATA --out CKPT --resume`` continues the epochs in ``CKPT`` only with what
they were trained with: a changed ``--lr``, ``--seed``, ``--no-augment``, ``--scans``, batch,
schedule …, or another DATA log (or other sequences) is refused naming the setting, both for a
partial run (after a kill) and for a finished one (which would otherwise be silently kept as it
is, or continued under settings the card would then claim for every epoch). ``--epochs`` and
``--stage`` may change (that is what a resume is for), and so may ``--device`` and ``--threads``.
A folder another command wrote (an adaptation, an import) is refused: it is not a training run.

Checked on the card alone, before any log is read for training or any network is built.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

from dsnet_core.errors import ConfigError

MAY_CHANGE = frozenset({"epochs", "stage", "device", "threads", "resume", "out", "init_from", "data"})
"""Options a resume may change (``data`` is checked against the card's training root instead)."""


class ResumeMismatchError(ConfigError):
    """A resume asked for other settings or data than the checkpoint was trained with."""


def check_train_resume(options: Any, command: str = "dsnet train") -> None:
    """Refuse a ``--resume`` into ``options.out`` that would mix settings, data or folder kinds.

    Args:
        options: a method's :class:`~tasks.methods.base.TrainOptions` (``out``, ``resume``, …).
        command: the command's name for the messages.

    Raises:
        ResumeMismatchError: naming each changed setting (recorded → given), the other data log,
            or the other kind of folder.
        CheckpointError: the card does not read.
    """
    from dsnet_core.model.card import CARD, card_json
    from dsnet_core.train import commit

    out = Path(options.out)
    if not options.resume:
        return
    if int(os.environ.get("RANK", "0")) == 0:  # under torchrun the main process owns the folder
        commit.recover(out)  # the card of the last committed epoch
    else:  # the other ranks read the card once rank 0 has finished a killed epoch's moves
        import time

        deadline = time.monotonic() + 60
        while (out / commit.PENDING / commit.COMMIT).exists() and time.monotonic() < deadline:
            time.sleep(0.1)
    if not (out / CARD).is_file():
        refuse_lost_card(out)
        return
    data = card_json(out).get("training_data") or {}
    if "adapt" in data:
        raise ResumeMismatchError(
            f"{out} is an adapted checkpoint (written by dsnet adapt): resume it with "
            f"`dsnet adapt LOG... --out {out} --resume`, or train from it with --init-from {out} --out NEW"
        )
    if "imported" in data:
        raise ResumeMismatchError(
            f"{out} is an imported checkpoint (dsnet import-checkpoint), not a training run to resume: "
            f"train from it with --init-from {out} --out NEW"
        )
    changed = changed_settings(options, data.get("train_config") or {})
    changed += changed_data(options, data)
    if changed:
        raise ResumeMismatchError(
            f"{out} was trained with other settings: {'; '.join(changed)}. Resume with the settings it "
            "was started with, or train into another --out"
        )


def changed_settings(options: Any, recorded: dict) -> list[str]:
    """``--lr: 0.001 → 0.002`` for each option whose value differs from the card's ``train_config``
    (only options the card records; :data:`MAY_CHANGE` excepted)."""
    out = []
    fields = type(options).model_fields
    for name in sorted(set(recorded) & set(fields) - MAY_CHANGE):
        given, was = getattr(options, name), recorded[name]
        if not _same(given, was):
            out.append(f"{_flag(name, given, fields[name].annotation)}: {was!r} → {given!r}")
    return out


def changed_data(options: Any, data: dict) -> list[str]:
    """The training (and validation) log and sequences, when given, against the card's record."""
    from dsnet_core.io.formats import open_log

    out = []
    root = data.get("root")
    if getattr(options, "data", None) is not None and root and "stream" not in data:
        given = open_log(options.data).root
        if Path(given) != Path(root):
            out.append(f"DATA: {root} → {given}")
    names = options.names(getattr(options, "sequences", None))
    if names is not None and data.get("sequences") is not None and list(names) != list(data["sequences"]):
        out.append(f"--sequences: {','.join(data['sequences'])} → {','.join(names)}")
    return out


def _same(given: Any, was: Any) -> bool:
    if isinstance(given, bool) or isinstance(was, bool):
        return type(given) is type(was) and given == was
    if isinstance(given, (int, float)) and isinstance(was, (int, float)):
        return math.isclose(float(given), float(was), rel_tol=1e-12, abs_tol=0.0)
    if isinstance(given, (tuple, list)) and isinstance(was, (tuple, list)):
        return len(given) == len(was) and all(_same(a, b) for a, b in zip(given, was, strict=True))
    return given == was


def _flag(name: str, given: Any, annotation: Any) -> str:
    flag = "--" + name.replace("_", "-")
    if annotation is bool and not given:
        return "--no-" + flag[2:]
    return flag


SAVED_FILES = ("model.safetensors", "shift.safetensors", "student.safetensors", "train_state.json",
               "train_state.safetensors")  # fmt: skip
"""Files of a saved epoch (a card is moved into place first: none of them is there without it)."""


def refuse_lost_card(out: Path) -> None:
    """A ``--resume`` into a folder holding a saved epoch's files but no card: the card was lost
    (deleted, or never restored from a copy); resuming would train afresh over them.

    Raises:
        CheckpointError: naming the card and the files found.
    """
    from dsnet_core.errors import CheckpointError
    from dsnet_core.model.card import CARD

    found = [name for name in SAVED_FILES if (Path(out) / name).is_file()]
    if found:
        raise CheckpointError(
            Path(out) / CARD,
            f"no model card beside {', '.join(found)}: the card is lost, so --resume cannot tell what was "
            "trained; restore it from a copy, or train into another --out (or delete the folder)",
        )
