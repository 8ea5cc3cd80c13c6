"""The network's input channels: what it reads of a cloud besides x, y, z.

A model's inputs are a comma-separated spec recorded in its card (``architecture.inputs``):

=====================  ========================================================================
spec                   the point features the network sees
=====================  ========================================================================
``xyz,remission``      the default (``raw``): remission 0–1 as the reader hands it
``xyz``                (``none``) no remission: the channel is zeroed, see below
``xyz,remission-rank`` (``rank``) each cloud's remission replaced by its empirical quantile
``…,height``           one more channel: height above the local ground (:mod:`.ground_height`)
=====================  ========================================================================

``none`` zeroes the remission channel rather than dropping it: the cloud stays ``(N, 4)`` and the
point MLP keeps its 9-feature layout, so every path that carries clouds (test-time augmentation,
the C_n lifting, D-PLS priors, checkpoints, the importers) is unchanged, and the network gets no
information from it: the point MLP starts with a batch norm, which maps a channel that is 0 for
every point to its learned bias, the same constant for every point of every scan.

The network builds its inputs itself (:meth:`dsnet_core.model.network.DSNet.forward` calls
:func:`build_inputs`), so training, validation, the shift stage's seeds, test-time augmentation and
the ``infer`` stage all compute them one way from the reader's ``(N, 4)`` clouds. A 4D volume is
one cloud here: its rank and its ground are those of the aligned volume the network is given.

Remission dropout (training only, ``remission_dropout = p``): with probability p a cloud's remission
is replaced by 0 before the transform (so a rank model sees the constant 0.5, the quantile every
point of a constant scan takes), teaching the network not to lean on it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from dsnet_core.errors import ConfigError, DataFormatError

if TYPE_CHECKING:
    import torch

REMISSION_MODES = ("raw", "none", "rank")
_REMISSION_TOKENS = {"remission": "raw", "remission-rank": "rank"}
DEFAULT_INPUTS = "xyz,remission"


class MissingInputError(DataFormatError):
    """A log lacks an input channel the model was trained with (e.g. no intensity for a model that
    reads remission)."""


@dataclass(frozen=True)
class InputSpec:
    """Parsed inputs.

    Attributes:
        remission: ``"raw"``, ``"none"`` or ``"rank"``.
        height: whether height above the local ground is one more point feature.
    """

    remission: str = "raw"
    height: bool = False

    @classmethod
    def parse(cls, text: str) -> InputSpec:
        """``"xyz,remission-rank,height"`` → the spec (tokens in any order, xyz required).

        Raises:
            ConfigError: an unknown token, xyz missing, a token twice or two remission tokens.
        """
        tokens = [t.strip() for t in str(text).split(",") if t.strip()]
        known = ("xyz", *_REMISSION_TOKENS, "height")
        for t in tokens:
            if t not in known:
                raise ConfigError(f"--inputs {text!r}: unknown input {t!r} (choose from {', '.join(known)})")
        if len(set(tokens)) != len(tokens):
            raise ConfigError(f"--inputs {text!r}: an input is named twice")
        if "xyz" not in tokens:
            raise ConfigError(f"--inputs {text!r}: xyz is required")
        rem = [t for t in tokens if t in _REMISSION_TOKENS]
        if len(rem) > 1:
            raise ConfigError(f"--inputs {text!r}: choose one of remission, remission-rank")
        return cls(remission=_REMISSION_TOKENS[rem[0]] if rem else "none", height="height" in tokens)

    def __str__(self) -> str:
        """The canonical spec: xyz, the remission token, height."""
        parts = ["xyz"]
        parts += [k for k, v in _REMISSION_TOKENS.items() if v == self.remission]
        return ",".join(parts + (["height"] if self.height else []))

    @property
    def extra_channels(self) -> int:
        """Point features beyond the 9 of :func:`~dsnet_core.model.cylinder.cylinder_features`."""
        return int(self.height)

    @property
    def needs_remission(self) -> str | None:
        """The input token that reads the log's intensity, or None (``xyz`` only)."""
        return {"raw": "remission", "rank": "remission-rank"}.get(self.remission)

    @property
    def is_raw(self) -> bool:
        """The default: the reader's cloud as it is (no channel built)."""
        return self.remission == "raw" and not self.height


def rank_normalise(values: torch.Tensor) -> torch.Tensor:
    """Each value's empirical quantile in [0, 1]: its mid-rank (ties share the mean of their
    ranks) divided by ``N - 1``; a single value or a constant cloud gives 0.5 everywhere.

    Depends only on the order of the values, so any strictly increasing transform of the input
    gives the identical output.

    Args:
        values: float ``(N,)``.

    Returns:
        float32 ``(N,)`` on the same device.
    """
    import torch

    n = values.numel()
    if n <= 1:
        return torch.full_like(values, 0.5, dtype=torch.float32)
    _, inverse, counts = torch.unique(values, sorted=True, return_inverse=True, return_counts=True)
    start = torch.cumsum(counts, 0) - counts
    mid = start.to(torch.float64) + (counts.to(torch.float64) - 1.0) / 2.0
    return (mid / (n - 1)).to(torch.float32)[inverse]


def build_inputs(
    clouds: list[torch.Tensor], spec: InputSpec, dropout: float = 0.0, training: bool = False
) -> list[torch.Tensor]:
    """The clouds as the network reads them.

    Args:
        clouds: float ``(N_b, 4)`` per cloud (x, y, z metres, remission 0–1).
        spec: the inputs.
        dropout: remission dropout probability, applied only when ``training`` (one draw per cloud
            from torch's default generator, which the trainer seeds per epoch).

    Returns:
        float32 ``(N_b, 4 + spec.extra_channels)`` per cloud: x, y, z, the remission channel (raw,
        0 or rank), then height above ground (metres) when asked for. The input tensors are not
        modified; with the default spec and no dropout they are returned as they are (their
        first four columns).
    """
    import torch

    if spec.is_raw and not (training and dropout > 0):
        return [c if c.shape[1] == 4 else c[:, :4] for c in clouds]
    from dsnet_core.model.ground_height import height_above_ground

    out = []
    for c in clouds:
        pts = c[:, :4].to(torch.float32)
        rem = pts[:, 3]
        if training and dropout > 0 and float(torch.rand(())) < dropout:
            rem = torch.zeros_like(rem)
        if spec.remission == "none":
            rem = torch.zeros_like(rem)
        elif spec.remission == "rank":
            rem = rank_normalise(rem)
        cols = [pts[:, :3], rem[:, None]]
        if spec.height:
            xyz = pts[:, :3].detach().cpu().numpy()
            h = torch.from_numpy(height_above_ground(xyz).astype(np.float32)).to(pts.device)
            cols.append(h[:, None])
        out.append(torch.cat(cols, dim=1))
    return out


def check_log_inputs(spec: InputSpec, log: str, sequence: str, convention: str, model: str) -> None:
    """Refuse a log sequence that lacks an input the model needs.

    Args:
        convention: the sequence's source intensity convention (``"none"``: no intensity channel).

    Raises:
        MissingInputError: one line naming the log, the sequence and the missing input.
    """
    need = spec.needs_remission
    if need is not None and convention == "none":
        raise MissingInputError(
            log,
            f"sequence {sequence} has no intensity channel, but model {model} needs input '{need}' "
            f"(its inputs: {spec}); label with a model trained with --inputs xyz",
        )
