"""Architecture of the MOST network (everything needed to rebuild it) and its Cartesian BEV grid.

The backbone part reuses :class:`~dsnet_core.model.presets.ModelConfig` (width, point MLP, cylinder
grid), so a MOST model and a DS-Net model of one preset share the same backbone shapes and the
MOST trainer can start from a DS-Net checkpoint's backbone.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

from dsnet_core.errors import ConfigError
from dsnet_core.model.presets import ModelConfig, get_preset

DEFAULT_SCANS = 3
MAX_BEV_CELLS = 1 << 24
"""The largest BEV grid taken (4096² cells). Its feature map is dense: ``bev_channels`` float32 per
cell and volume, 2 GiB at 32 channels (the default 100 m / 0.5 m grid has 40,000 cells, 5 MB)."""


@dataclass(frozen=True)
class BevGrid:
    """A square Cartesian bird's-eye-view grid centred on the sensor.

    Attributes:
        half_extent: the grid covers ``[-half_extent, half_extent]²`` metres in (x, y).
        cell: cell size, metres.
    """

    half_extent: float = 50.0
    cell: float = 0.5

    def __post_init__(self) -> None:
        if not (self.half_extent > 0 and self.cell > 0):
            raise ConfigError(f"BEV grid needs positive half_extent and cell, got {self}")
        if self.size**2 > MAX_BEV_CELLS:
            raise ConfigError(
                f"BEV grid of {self.size}² = {self.size**2:.3g} cells (half_extent {self.half_extent} m, "
                f"cell {self.cell} m) is more than the {MAX_BEV_CELLS:.3g} (4096²) its dense maps may take"
            )

    @property
    def size(self) -> int:
        """Cells along x and along y."""
        return math.ceil(2 * self.half_extent / self.cell)


@dataclass(frozen=True)
class MostConfig:
    """The MOST network.

    Attributes:
        backbone: point MLP, U-Net width, cylinder grid and number of semantic classes.
        things: thing train ids, one heatmap channel each, in this order.
        bev: the Cartesian BEV grid of the detection branch.
        bev_level: U-Net decoder level flattened to BEV (0 = full resolution, 4 = bottleneck;
            level ``l`` has stride ``2^l`` in ρ and φ). See ``docs/most.md`` for why 2.
        bev_channels: channels of the BEV feature map ``F^bev``.
        mem_widths: hidden widths of PointSegMLP (4 layers with the output).
        time_feature: the per-point input carries the relative time (10 inputs, else 9).
    """

    backbone: ModelConfig = field(default_factory=lambda: get_preset("tiny"))
    things: tuple[int, ...] = (1, 2, 3, 4, 5, 6, 7, 8)
    bev: BevGrid = field(default_factory=BevGrid)
    bev_level: int = 2
    bev_channels: int = 32
    mem_widths: tuple[int, ...] = (64, 64, 32)
    time_feature: bool = True

    def __post_init__(self) -> None:
        if not 0 <= self.bev_level <= 4:
            raise ConfigError(f"bev_level must be 0..4, got {self.bev_level}")
        if not self.things or max(self.things) >= self.backbone.num_classes or min(self.things) < 1:
            raise ConfigError(f"thing ids {self.things} must lie in 1..{self.backbone.num_classes - 1}")

    @property
    def num_things(self) -> int:
        return len(self.things)

    @property
    def in_features(self) -> int:
        """Per-point input features: the 9 cylinder features, plus the relative time."""
        return 10 if self.time_feature else 9

    def to_dict(self) -> dict:
        return {
            "method": "most",
            "backbone": self.backbone.to_dict(),
            "things": list(self.things),
            "bev": asdict(self.bev),
            "bev_level": self.bev_level,
            "bev_channels": self.bev_channels,
            "mem_widths": list(self.mem_widths),
            "time_feature": self.time_feature,
        }

    @classmethod
    def from_dict(cls, d: dict) -> MostConfig:
        try:
            return cls(
                backbone=ModelConfig.from_dict(d["backbone"]),
                things=tuple(int(t) for t in d["things"]),
                bev=BevGrid(float(d["bev"]["half_extent"]), float(d["bev"]["cell"])),
                bev_level=int(d["bev_level"]),
                bev_channels=int(d["bev_channels"]),
                mem_widths=tuple(int(v) for v in d["mem_widths"]),
                time_feature=bool(d["time_feature"]),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise ConfigError(f"invalid MOST config {d!r}: {exc}") from exc
