"""Every method's checkpoints, described once per method, above the packages of the networks
(``model/``, ``most/``): a card kind per checkpoint format (:data:`CARD_KINDS`: which method's
network a folder holds and how its card is read) and a :class:`Checkpoints` description per method
(its bundled models, resolving a ``--checkpoint`` or the bundled one, reading its card with a hint
naming the method of another kind's card). A method object (``tasks.methods``) holds its
description; stages resolve through it; :func:`checkpoint_digest` reads any card through its kind.

The bundled DS-Net models live in the package at ``dsnet_core/data/models/tiny-v2/`` (single
scans) and ``tiny-v2-4d/`` (its joint 2-scan fine-tune), shipped by ``pyproject``'s package data;
``most/`` (and ``most-1/`` when present) and ``dpls/`` are MOST's and D-PLS's; ``tiny-v2-eq4/`` is
the C4-equivariant DS-Net. ``tiny/`` and ``tiny-4d/`` are the predecessors the MOST and D-PLS
models started from, kept for the benchmarks that compare with them; nothing defaults to them.
When a copy of the package lacks a model, ``bundled`` returns None and callers say so.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path

from dsnet_core.model.card import (
    CARD,
    FORMAT,
    SHIFT_WEIGHTS,
    CheckpointError,
    ModelCard,
    card_json,
    read_card,
    sha256_file,
)
from dsnet_core.most.card import MOST_FORMAT, read_most_card

MODELS = Path(__file__).resolve().parent / "data" / "models"


@dataclass(frozen=True)
class CardKind:
    """One checkpoint format: the method whose network it holds (its title for messages) and the
    reader that validates its card."""

    format: str
    method: str
    title: str
    read: Callable[[Path], ModelCard]


CARD_KINDS: dict[str, CardKind] = {
    k.format: k
    for k in (
        CardKind(FORMAT, "dsnet", "DS-Net", read_card),
        CardKind(MOST_FORMAT, "most", "MOST", read_most_card),
    )
}
"""Every checkpoint format by its card's ``format`` (D-PLS's network is a DS-Net with a prior
input: its cards are DS-Net cards)."""


def card_kind(path: str | Path) -> CardKind:
    """The kind of the checkpoint folder ``path`` by its card's ``format``.

    Raises:
        CheckpointError: no readable card, or an unknown format (naming the known ones).
    """
    fmt = card_json(Path(path)).get("format")
    if fmt not in CARD_KINDS:
        raise CheckpointError(
            Path(path) / CARD, f"unknown checkpoint format {fmt!r} (known: {sorted(CARD_KINDS)})"
        )
    return CARD_KINDS[fmt]


def checkpoint_method(path: str | Path) -> str:
    """Which method's network a checkpoint folder holds (its :class:`CardKind`'s ``method``)."""
    return card_kind(path).method


@dataclass(frozen=True)
class Checkpoints:
    """A method's checkpoints.

    Attributes:
        title: the method's name in messages (``MOST``).
        kind: the card kind its checkpoints have.
        bundled_names: the bundled folders (under :data:`MODELS`) for k scans, in preference order.
        hint: how to get one when none is given and none is bundled (the end of the error).
    """

    title: str
    kind: CardKind
    bundled_names: Callable[[int], tuple[str, ...]]
    hint: str

    def bundled(self, scans: int = 1) -> Path | None:
        """The first bundled checkpoint of :attr:`bundled_names` for ``scans``, or None."""
        for name in self.bundled_names(scans):
            if _is_checkpoint(MODELS / name):
                return MODELS / name
        return None

    def read_card(self, path: str | Path) -> ModelCard:
        """The card of ``path``, validated by this method's card kind.

        Raises:
            CheckpointError: no card, a malformed one, or another kind's (naming its method).
        """
        path = Path(path).expanduser()
        fmt = card_json(path).get("format")
        other = CARD_KINDS.get(fmt)
        if other is not None and other is not self.kind:
            raise CheckpointError(
                path / CARD,
                f"not a {self.title} checkpoint (format {fmt!r}, expected {self.kind.format}) — a "
                f"{other.title} checkpoint: label with --method {other.method}",
            )
        return self.kind.read(path)

    def resolve(self, path: str | Path | None, scans: int = 1) -> Path:
        """``path`` (its card read: a typed error naming the file when it is not one of this
        method's checkpoints), or the bundled model for ``scans`` when None.

        Raises:
            CheckpointError: None given and none bundled, or ``path`` is not such a checkpoint.
        """
        if path is None:
            found = self.bundled(scans)
            if found is None:
                raise CheckpointError(MODELS, f"no bundled {self.title} model: {self.hint}")
            return found
        path = Path(path).expanduser()
        self.read_card(path)
        return path


def _is_checkpoint(path: Path) -> bool:
    return (path / "card.json").is_file() and (path / "model.safetensors").is_file()


def _by_scans(names: Mapping[int, str]) -> Callable[[int], tuple[str, ...]]:
    """The bundled name for k (the largest key ≤ k first), then the single-scan one."""

    def pick(scans: int) -> tuple[str, ...]:
        keys = sorted((k for k in names if k <= max(scans, 1)), reverse=True)
        return tuple(dict.fromkeys([names[k] for k in keys] + [names[min(names)]]))

    return pick


DSNET = Checkpoints(
    "DS-Net",
    CARD_KINDS[FORMAT],
    _by_scans({1: "tiny-v2", 2: "tiny-v2-4d"}),
    "pass a checkpoint (dsnet label --checkpoint PATH)",
)
"""DS-Net's: ``tiny-v2`` (single scans) and ``tiny-v2-4d`` (every k > 1; the single-scan one when
the 4D one is not bundled)."""
DSNET_EQUIVARIANT = {
    n: Checkpoints(
        f"C{n}-equivariant DS-Net",
        CARD_KINDS[FORMAT],
        lambda scans, n=n: (f"tiny-v2-eq{n}",),
        f"pass a checkpoint (dsnet label --equivariant {n} --checkpoint PATH)",
    )
    for n in (4,)
}
"""DS-Net's C_n-equivariant models by n (``dsnet label --equivariant n`` without ``--checkpoint``)."""
MOST = Checkpoints(
    "MOST",
    CARD_KINDS[MOST_FORMAT],
    lambda scans: ("most-1", "most") if scans <= 1 else ("most",),
    "pass a MOST checkpoint (dsnet label --method most --checkpoint PATH; train one with dsnet train most)",
)
"""MOST's: the accumulated-input model (k = 3), and for k = 1 a single-scan one when bundled."""
DPLS = Checkpoints(
    "D-PLS",
    CARD_KINDS[FORMAT],
    lambda scans: ("dpls",),
    "pass a D-PLS checkpoint (dsnet label --method dpls --checkpoint PATH; train one with dsnet train dpls)",
)
"""D-PLS's instance network (``dpls/``, one model for every k)."""


def bundled_dir(scans: int = 1) -> Path:
    """Where DS-Net's bundled model for ``scans``-scan volumes lives inside the package (whether or
    not this copy holds it)."""
    return MODELS / DSNET.bundled_names(scans)[0]


def bundled_checkpoint(scans: int = 1) -> Path | None:
    """DS-Net's bundled checkpoint for ``scans`` (:attr:`DSNET`'s :meth:`~Checkpoints.bundled`)."""
    return DSNET.bundled(scans)


def resolve_checkpoint(path: str | Path | None, scans: int = 1) -> Path:
    """DS-Net's :meth:`~Checkpoints.resolve` (the default method's: the demo and the prior use it)."""
    return DSNET.resolve(path, scans)


def checkpoint_digest(path: str | Path) -> str:
    """A content digest of a checkpoint of any kind: the card (read by its :func:`card_kind`, which
    holds the weights' sha256) and the shifting weights' sha256. Cheap: the network weights are not
    re-read (loading the model verifies them against the card's hash).

    Returns:
        32 hex digits.
    """
    path = Path(path)
    card = card_kind(path).read(path)
    h = hashlib.blake2b(digest_size=16)
    h.update(
        json.dumps({k: v for k, v in card.__dict__.items() if k != "code_version"}, sort_keys=True).encode()
    )
    shift = path / SHIFT_WEIGHTS
    h.update(sha256_file(shift).encode() if shift.is_file() else b"no-shift-weights")
    return h.hexdigest()
