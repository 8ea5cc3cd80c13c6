"""Stand-ins for model stages in stage tests: a ``fuse`` whose labels a test writes itself, on
align's volumes, with the SemanticKITTI class map recorded as a model stage records it."""

from __future__ import annotations

from dsnet_core.labels import class_map_of, load_label_map
from storage.contract import ArraySpec
from tasks.base import CLASS_MAP, Plan, Stage, StageConfig, StageContext
from tasks.fuse import INSTANCES

LM = load_label_map("semantic-kitti")


def align_shaped_plan(ctx: StageContext) -> Plan:
    """One item per align volume, align's padding, and the class map of :data:`LM`."""
    align = ctx.manifest("align")
    return Plan(
        n_items=align.n_items, max_points=int(align.plan["max_points"]), meta={CLASS_MAP: class_map_of(LM)}
    )


class FuseStandIn(Stage):
    """Declared as ``fuse`` (``sem``, ``inst`` per volume and the instances table); a subclass sets
    ``version`` and ``run_block``."""

    name = "fuse"
    upstream = ("align",)
    Config = StageConfig
    item = "volume"
    arrays = (ArraySpec("sem", "uint8"), ArraySpec("inst", "int32"))
    tables = (INSTANCES,)

    def plan(self, ctx: StageContext) -> Plan:
        return align_shaped_plan(ctx)
