"""Model configuration and the width presets (``tiny`` for CI and the demo, ``small``, ``paper``)."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

from dsnet_core.errors import ConfigError
from dsnet_core.model.cylinder import CylinderGrid


@dataclass(frozen=True)
class ModelConfig:
    """Architecture of the DS-Net network (everything needed to rebuild it).

    Attributes:
        width: base width ``w`` of the U-Net (the paper uses 32).
        num_classes: semantic classes including the ignore class 0.
        point_mlp: hidden and output widths of the per-point MLP (input is the 9 features).
        compress: voxel feature width after max-pooling and compression.
        ins_dim: width of the per-point instance feature handed to the shifting module.
        grid: the cylindrical grid.
        prior_channels: per-point semantic-prior channels appended to the 9 point features
            (D-PLS's prior-conditioned instance network; 0 = none).
        semantic_head: whether the network predicts semantics (a D-PLS instance network does not:
            its semantics are the prior's).
        equivariant: ``n`` of the C_n lifting (``dsnet_core.model.equivariant``); 1 = plain.
        pooling: invariant pooling of the semantic logits over the n rotations, "mean" or "max".
    """

    width: int = 32
    num_classes: int = 20
    point_mlp: tuple[int, ...] = (64, 128, 256, 64)
    compress: int = 16
    ins_dim: int = 32
    grid: CylinderGrid = field(default_factory=CylinderGrid)
    prior_channels: int = 0
    semantic_head: bool = True
    equivariant: int = 1
    pooling: str = "mean"

    def __post_init__(self) -> None:
        if self.prior_channels < 0:
            raise ConfigError(f"prior_channels must be >= 0, got {self.prior_channels}")
        if self.equivariant < 1:
            raise ConfigError(f"--equivariant needs n >= 1, got {self.equivariant}")
        if self.pooling not in POOLINGS:
            raise ConfigError(f"unknown invariant pooling '{self.pooling}' (choose {', '.join(POOLINGS)})")

    def to_dict(self) -> dict:
        """The architecture as a card records it. The D-PLS and equivariant fields appear only when
        they differ from a plain DS-Net's, so cards written before they existed compare equal."""
        d = asdict(self)
        d["point_mlp"] = list(self.point_mlp)
        d["grid"] = self.grid.to_dict()
        for key, default in _OPTIONAL.items():
            if d[key] == default:
                del d[key]
        return d

    @classmethod
    def from_dict(cls, d: dict) -> ModelConfig:
        try:
            return cls(
                width=int(d["width"]),
                num_classes=int(d["num_classes"]),
                point_mlp=tuple(int(v) for v in d["point_mlp"]),
                compress=int(d["compress"]),
                ins_dim=int(d["ins_dim"]),
                grid=CylinderGrid.from_dict(d["grid"]),
                **{key: type(default)(d.get(key, default)) for key, default in _OPTIONAL.items()},
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise ConfigError(f"invalid model config {d!r}: {exc}") from exc


POOLINGS = ("mean", "max")
_OPTIONAL = {"prior_channels": 0, "semantic_head": True, "equivariant": 1, "pooling": "mean"}


PRESETS: dict[str, ModelConfig] = {
    "tiny": ModelConfig(width=4, point_mlp=(32, 64, 64, 32)),
    "small": ModelConfig(width=8, point_mlp=(64, 128, 128, 64)),
    "paper": ModelConfig(width=32),
}


def get_preset(name: str) -> ModelConfig:
    """The named preset's config; raises :class:`ConfigError` naming the choices."""
    if name not in PRESETS:
        raise ConfigError(f"unknown model preset '{name}' (choose from {', '.join(PRESETS)})")
    return PRESETS[name]
