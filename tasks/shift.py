"""Stage ``shift``: class-agnostic instance clustering of each volume's predicted thing points.

The clusterer comes from :mod:`dsnet_core.instance.clustering` through its pydantic config (``kind`` =
``dynamic_shift`` by default; ``meanshift``, ``dbscan``, ``hdbscan``, ``bfs`` for the ablation
and as fallbacks). Its input is the thing points (predicted thing classes) with their regressed
centres ``xyz + offset`` and instance features. Output per point: ``instance`` (int32 raw ids
1..K, volume-local; 0 for stuff); with dynamic shifting also ``seed_position`` (the converged
position at every FPS seed, NaN elsewhere) for inspection.

Dynamic shifting needs trained shifting MLPs: they are read from the infer checkpoint's
``shift.safetensors``. A checkpoint without them falls back to fixed weights (0, 1, 0) — plain
blurring mean shift with the middle bandwidth — logged as a warning and counted in the manifest
(``fixed_shift_weights``). Default settings follow the volumes: 3D (bandwidths 0.2/1.7/3.2 m,
10 000 seeds) for k = 1, 4D (0.2/1.8/3.4 m, 20 000 seeds) for k > 1.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from typing import Any

import numpy as np
from pydantic import Field, field_validator

from dsnet_core.instance.clustering_config import ClustererConfig, DynamicShiftConfig
from storage.contract import ArraySpec
from tasks.align import volume_scans
from tasks.base import ItemResult, Plan, Stage, StageConfig, StageContext

log = logging.getLogger(__name__)

FALLBACK_WEIGHTS = (0.0, 1.0, 0.0)


class ShiftConfig(StageConfig):
    """Clustering settings.

    Attributes:
        clusterer: a clusterer config (``{"kind": "dbscan", "eps": 0.5}``); None = dynamic shifting
            with the 3D or 4D defaults by the volumes' k.
        keep_seeds: also store the seeds' converged positions (dynamic shifting only).
    """

    clusterer: ClustererConfig | None = Field(None)
    keep_seeds: bool = True

    @field_validator("clusterer", mode="before")
    @classmethod
    def _kind_alone(cls, value: Any) -> Any:
        """A kind's name alone (``meanshift``, as a config file or ``--set shift.clusterer=meanshift``
        writes it) is that kind with its defaults."""
        return {"kind": value} if isinstance(value, str) else value


def effective_clusterer(config: ShiftConfig, scans: int):
    """The clusterer config a run uses: the configured one, or dynamic shifting for k scans."""
    if config.clusterer is not None:
        return config.clusterer
    return DynamicShiftConfig() if scans <= 1 else DynamicShiftConfig.for_4d()


def cluster_volume(clusterer, xyz: np.ndarray, centres: np.ndarray, features: np.ndarray | None):
    """Ids of the thing points, and for dynamic shifting the seeds and their converged positions.

    Args:
        clusterer: from :func:`dsnet_core.instance.clustering.get_clusterer`.
        xyz, centres: float32 ``(M, 3)`` thing points and regressed centres, metres.
        features: ``(M, D)`` instance features.

    Returns:
        ``(ids int64 (M,), seeds int64 (S,) or None, converged float32 (S, 3) or None)``; the ids
        equal ``clusterer.cluster(xyz, centres, features)``.
    """
    from dsnet_core.instance.clustering import DynamicShiftClusterer

    if not isinstance(clusterer, DynamicShiftClusterer) or xyz.shape[0] < 2:
        return clusterer.cluster(xyz, centres, features), None, None
    out = clusterer.run(xyz, centres, features)
    return out.ids, out.seeds, out.converged


MODEL_ARRAYS = ("sem", "offsets", "features")
"""What ``shift`` (and ``fuse``) read of their source: a model stage's per-volume predicted class,
offsets to instance centres and instance features (``infer``'s arrays; D-PLS's stage has them too)."""


class ShiftStage(Stage):
    """Clusters the thing points of ``source``, any stage that declares :data:`MODEL_ARRAYS`."""

    name = "shift"
    version = "1"
    Config = ShiftConfig
    item = "volume"
    arrays = (
        ArraySpec("instance", "int32", doc="raw instance id 1..K on thing points, 0 elsewhere"),
        ArraySpec(
            "seed_position",
            "float32",
            trailing=(3,),
            optional=True,
            doc="converged position (metres) at the points chosen as shifting seeds, NaN elsewhere",
        ),
    )

    def __init__(self, source: str = "infer") -> None:
        self.source = source
        self.upstream = (source,)

    def check_sources(self, pipeline) -> None:
        self.require(pipeline, self.source, MODEL_ARRAYS)

    def reads(self, pipeline) -> dict[str, tuple[str, ...]]:
        """The volumes' points, of align (upstream of its source, which reads them too)."""
        return {"align": ("points",)}

    def plan(self, ctx: StageContext) -> Plan:
        infer = ctx.manifest(self.source)
        cfg = effective_clusterer(ctx.config, volume_scans(ctx))
        dynamic = isinstance(cfg, DynamicShiftConfig)
        return Plan(
            n_items=infer.n_items,
            max_points=int(infer.plan["max_points"]),
            omit=() if dynamic and ctx.config.keep_seeds else ("seed_position",),
            meta={
                "clusterer": cfg.model_dump(mode="json"),
                "checkpoint": infer.plan["checkpoint"],
                "seeds": dynamic and ctx.config.keep_seeds,
            },
        )

    def run_block(self, ctx: StageContext, items: list[int]) -> Iterator[ItemResult]:
        from pydantic import TypeAdapter

        from dsnet_core.instance.clustering import get_clusterer
        from dsnet_core.instance.shifting import DynamicShift
        from dsnet_core.model.bundle import load_shift_weights
        from dsnet_core.model.checkpoint import read_card

        cfg = TypeAdapter(ClustererConfig).validate_python(ctx.plan["clusterer"])
        fixed = 0
        weights = None
        if isinstance(cfg, DynamicShiftConfig):
            # the MLPs read the model's instance features: their width is the checkpoint's ins_dim
            width = read_card(ctx.plan["checkpoint"]).config.ins_dim
            if width != cfg.feature_dim:
                cfg = cfg.model_copy(update={"feature_dim": width})
            weights = load_shift_weights(ctx.plan["checkpoint"])
            if weights is None:
                log.warning(
                    "checkpoint %s has no shifting weights; dynamic shifting uses fixed weights %s",
                    ctx.plan["checkpoint"],
                    FALLBACK_WEIGHTS,
                )
                weights = DynamicShift.with_fixed_weights(
                    FALLBACK_WEIGHTS, cfg.bandwidths, iterations=cfg.iterations, feature_dim=cfg.feature_dim
                )
                fixed = 1
        clusterer = get_clusterer(cfg, weights)
        thing_lut = ctx.label_map.is_thing()
        align = ctx.arrays("align")
        infer = ctx.arrays(self.source)
        for item in items:
            xyz = align.read_item(item, ["points"])["points"][:, :3]
            inf = infer.read_item(item, ["sem", "offsets", "features"])
            thing = thing_lut[inf["sem"]]
            t_xyz = np.ascontiguousarray(xyz[thing])
            centres = np.ascontiguousarray(t_xyz + inf["offsets"][thing], dtype=np.float32)
            feats = np.ascontiguousarray(inf["features"][thing])
            ids, seeds, converged = cluster_volume(clusterer, t_xyz, centres, feats)
            n = int(xyz.shape[0])
            instance = np.zeros(n, np.int32)
            instance[thing] = ids
            arrays = {"instance": instance}
            if ctx.plan["seeds"]:
                pos = np.full((n, 3), np.nan, np.float32)
                if seeds is not None:
                    pos[np.flatnonzero(thing)[seeds]] = converged
                arrays["seed_position"] = pos
            yield ItemResult(
                item,
                arrays=arrays,
                n_points=n,
                counts={
                    "volumes": 1,
                    "points": n,
                    "thing_points": int(thing.sum()),
                    "instances": int(ids.max(initial=0)),
                    "fixed_shift_weights": fixed,
                },
            )
