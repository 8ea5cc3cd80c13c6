"""The clusterers' configs: pydantic models, a discriminated union on ``kind``.

Kept apart from the algorithms (``dsnet_core.instance.clustering``) so that stages and command lines can
parse and fingerprint a clusterer choice without importing torch. The bandwidths are the paper's.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field

BANDWIDTHS_3D: tuple[float, ...] = (0.2, 1.7, 3.2)
"""DS-Net's flat-kernel bandwidth candidates (metres) for single scans."""
BANDWIDTHS_4D: tuple[float, ...] = (0.2, 1.8, 3.4)
"""4D-DS-Net's candidates for multi-scan volumes."""


class _ClustererConfig(BaseModel):
    """Base of the clusterer configs: frozen, unknown keys rejected."""

    model_config = ConfigDict(extra="forbid", frozen=True)


class DynamicShiftConfig(_ClustererConfig):
    """Dynamic shifting. Weights come from a checkpoint (see :func:`get_clusterer`)."""

    kind: Literal["dynamic_shift"] = "dynamic_shift"
    bandwidths: tuple[float, ...] = BANDWIDTHS_3D
    iterations: int = Field(4, ge=0)
    feature_dim: int = Field(32, ge=1)
    n_seeds: int = Field(10_000, ge=1)
    final_bandwidth: float = Field(0.65, gt=0)
    kernel: Literal["dense", "neighbors"] = "neighbors"
    device: str = "cpu"

    @classmethod
    def for_4d(cls, **overrides) -> DynamicShiftConfig:
        """The 4D-DS-Net setting: bandwidths (0.2, 1.8, 3.4) m and 20 000 seeds."""
        return cls(**{"bandwidths": BANDWIDTHS_4D, "n_seeds": 20_000, **overrides})


class MeanShiftConfig(_ClustererConfig):
    kind: Literal["meanshift"] = "meanshift"
    bandwidth: float = Field(1.2, gt=0)


class DBSCANConfig(_ClustererConfig):
    kind: Literal["dbscan"] = "dbscan"
    eps: float = Field(0.4, gt=0)
    min_samples: int = Field(10, ge=1)
    assign_noise: bool = True


class HDBSCANConfig(_ClustererConfig):
    kind: Literal["hdbscan"] = "hdbscan"
    min_cluster_size: int = Field(20, ge=2)
    assign_noise: bool = True


class BFSConfig(_ClustererConfig):
    kind: Literal["bfs"] = "bfs"
    radius: float = Field(0.3, gt=0)
    min_size: int = Field(5, ge=1)
    assign_noise: bool = True


ClustererConfig = Annotated[
    DynamicShiftConfig | MeanShiftConfig | DBSCANConfig | HDBSCANConfig | BFSConfig,
    Field(discriminator="kind"),
]
