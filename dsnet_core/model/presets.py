"""Model configuration and the presets: widths ``tiny`` (CI and the demo), ``small``, ``paper``, and the
shapes of the released reference networks, ``reference`` (DS-Net / 4D-DS-Net as trained with spconv 1.x)
and ``cylinder3d`` (Cylinder3D's semantic network), which the checkpoint importer targets."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

from dsnet_core.errors import ConfigError
from dsnet_core.model.grid import CylinderGrid
from dsnet_core.model.inputs import DEFAULT_INPUTS, InputSpec

#: How the backbone's submanifold convolutions find their neighbours.
#: ``"per-layer"``: every layer with its own kernel shape (the architecture as declared).
#: ``"spconv1-shared"``: spconv 1.x's behaviour, which the reference networks were trained with:
#: layers sharing an ``indice_key`` reuse the rulebook of the first one, so every layer of a block
#: acts with the first layer's kernel shape (see ``dsnet_core/model/backbone.py``).
RULEBOOKS = ("per-layer", "spconv1-shared")


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
        rulebooks: one of :data:`RULEBOOKS`.
        inputs: the input channels (:mod:`dsnet_core.model.inputs`): ``"xyz,remission"`` (the
            reader's remission, the default), ``"xyz"`` (none), ``"xyz,remission-rank"``, each
            optionally with ``",height"`` (height above the local ground, one more point feature).
        remission_dropout: training only: the probability a cloud's remission is replaced by a
            constant (:func:`dsnet_core.model.inputs.build_inputs`); recorded with the inputs.
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
    rulebooks: str = "per-layer"
    inputs: str = DEFAULT_INPUTS
    remission_dropout: float = 0.0

    def __post_init__(self) -> None:
        spec = InputSpec.parse(self.inputs)  # raises ConfigError naming a bad token
        object.__setattr__(self, "inputs", str(spec))  # canonical order, so cards compare equal
        if not 0.0 <= self.remission_dropout < 1.0:
            raise ConfigError(f"remission dropout must be in [0, 1), got {self.remission_dropout}")
        if self.rulebooks not in RULEBOOKS:
            raise ConfigError(f"unknown rulebooks '{self.rulebooks}' (choose from {', '.join(RULEBOOKS)})")
        if self.prior_channels < 0:
            raise ConfigError(f"prior_channels must be >= 0, got {self.prior_channels}")
        if self.equivariant < 1:
            raise ConfigError(f"--equivariant needs n >= 1, got {self.equivariant}")
        if self.pooling not in POOLINGS:
            raise ConfigError(f"unknown invariant pooling '{self.pooling}' (choose {', '.join(POOLINGS)})")

    @property
    def input_spec(self) -> InputSpec:
        """The parsed :attr:`inputs`."""
        return InputSpec.parse(self.inputs)

    def to_dict(self) -> dict:
        """The architecture as a card records it. The D-PLS, equivariant and rulebooks fields appear
        only when they differ from a plain DS-Net's, so cards written before they existed compare equal."""
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
        except KeyError as exc:
            raise ConfigError(f"model config has no field {exc}") from exc
        except (TypeError, ValueError) as exc:  # one line: the config itself is not repeated
            raise ConfigError(str(exc)) from exc


POOLINGS = ("mean", "max")
_OPTIONAL = {
    "prior_channels": 0,
    "semantic_head": True,
    "equivariant": 1,
    "pooling": "mean",
    "rulebooks": "per-layer",
    "inputs": DEFAULT_INPUTS,
    "remission_dropout": 0.0,
}

#: DS-Net's released networks (hongfz16/DS-Net cfgs/release/*.yaml): grid 480×360×32 over
#: ρ 3..50 m, φ ±π, z −3..1.5 m with the reference cell convention, spconv 1.x rulebooks.
REFERENCE = ModelConfig(
    width=32,
    point_mlp=(64, 128, 256, 64),
    grid=CylinderGrid(convention="reference"),
    rulebooks="spconv1-shared",
)
#: Cylinder3D's released SemanticKITTI network (xinge008/Cylinder3D config/semantickitti.yaml):
#: point MLP output 256, grid over ρ 0..50 m, φ ±3.1415926, z −4..2 m.
CYLINDER3D = ModelConfig(
    width=32,
    point_mlp=(64, 128, 256, 256),
    grid=CylinderGrid(
        min_bound=(0.0, -3.1415926, -4.0), max_bound=(50.0, 3.1415926, 2.0), convention="reference"
    ),
    rulebooks="spconv1-shared",
)


PRESETS: dict[str, ModelConfig] = {
    "tiny": ModelConfig(width=4, point_mlp=(32, 64, 64, 32)),
    "small": ModelConfig(width=8, point_mlp=(64, 128, 128, 64)),
    "paper": ModelConfig(width=32),
    "reference": REFERENCE,
    "cylinder3d": CYLINDER3D,
}


def get_preset(name: str) -> ModelConfig:
    """The named preset's config; raises :class:`ConfigError` naming the choices."""
    if name not in PRESETS:
        raise ConfigError(f"unknown model preset '{name}' (choose from {', '.join(PRESETS)})")
    return PRESETS[name]
