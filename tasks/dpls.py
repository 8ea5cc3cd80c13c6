"""Stage ``dpls``: D-PLS's prior-conditioned instance network on every volume (paper Sec. 3.2).

The volume's points go through the network with the ``prior`` stage's class per point appended
one-hot (:class:`dsnet_core.model.dpls.DplsPredictor`); the network regresses offsets to instance
centres and instance features, and predicts no semantics: ``sem`` and ``probs`` are the prior's.
It writes the arrays ``infer`` writes (``sem``, ``probs``, ``offsets``, ``features``), so ``shift``
and ``fuse`` read it as they read ``infer`` (``ShiftStage(source="dpls")``); the majority vote of
``fuse`` is then over the prior's classes.

The prior's class map must be the checkpoint's (same class names and thing ids), else the plan
is refused naming both. The fingerprint holds the checkpoint's content digest and the prior
stage's fingerprint, so a new prior recomputes ``dpls`` and what follows, not ``align``.
"""

from __future__ import annotations

from collections.abc import Iterator

from tasks.base import CLASS_MAP, ItemResult, Plan, Stage, StageConfig, StageContext
from tasks.infer import InferStage, _check_device, model_meta, thing_only


class DplsConfig(StageConfig):
    """Model settings.

    Attributes:
        checkpoint: a D-PLS checkpoint folder; None = the bundled D-PLS model.
        device: torch device.
    """

    checkpoint: str | None = None
    device: str = "cpu"


class DplsStage(Stage):
    name = "dpls"
    upstream = ("align", "prior")
    version = "1"
    Config = DplsConfig
    item = "volume"
    arrays = InferStage.arrays

    @staticmethod
    def checkpoint(ctx: StageContext):
        from dsnet_core.checkpoints import DPLS

        return DPLS.resolve(ctx.config.checkpoint)

    def inputs(self, ctx: StageContext) -> str:
        from dsnet_core.checkpoints import checkpoint_digest

        return "checkpoint:" + checkpoint_digest(self.checkpoint(ctx))

    def plan(self, ctx: StageContext) -> Plan:
        from dsnet_core.errors import CheckpointError, ConfigError
        from dsnet_core.model.checkpoint import CARD, read_card
        from dsnet_core.model.dpls import is_dpls

        _check_device(ctx.config.device)
        align = ctx.manifest("align")
        prior = ctx.manifest("prior")
        path = self.checkpoint(ctx).resolve()
        card = read_card(path)
        cfg = card.config
        if not is_dpls(cfg):
            raise CheckpointError(
                path / CARD,
                "a DS-Net checkpoint without a semantic-prior input: label with --method dsnet, or train "
                "a D-PLS one with dsnet train dpls",
            )
        theirs, ours = prior.plan[CLASS_MAP], card.class_map
        if theirs["class_names"] != ours["class_names"] or theirs["things"] != ours["things"]:
            raise ConfigError(
                f"the semantic prior's classes (label map {theirs['name']!r}: {len(theirs['class_names'])} "
                f"train ids) are not those of D-PLS checkpoint {path} (label map {ours['name']!r}: "
                f"{len(ours['class_names'])}); give a --prior-label-map that maps the prior's raw ids into "
                "the model's classes"
            )
        return Plan(
            n_items=align.n_items,
            max_points=int(align.plan["max_points"]),
            meta=model_meta(path, card),
            dims={"classes": cfg.prior_channels, "features": cfg.ins_dim},
        )

    def run_block(self, ctx: StageContext, items: list[int]) -> Iterator[ItemResult]:
        from dsnet_core.labels import label_map_from_class_map
        from dsnet_core.model.dpls import DplsPredictor

        label_map = label_map_from_class_map(ctx.plan[CLASS_MAP])
        predictor = DplsPredictor.from_checkpoint(
            ctx.plan["checkpoint"], device=ctx.config.device, expect_label_map=label_map
        )
        thing = label_map.is_thing()
        align, prior = ctx.arrays("align"), ctx.arrays("prior")
        for item in items:
            points = align.read_item(item, ["points"])["points"]
            pri = prior.read_item(item, ["prior", "sem"])
            offsets, features = predictor.predict(points, pri["sem"])
            n = int(points.shape[0])
            is_thing = thing[pri["sem"]]  # shift reads offsets and features on these points only
            yield ItemResult(
                item,
                arrays={
                    "sem": pri["sem"],
                    "probs": pri["prior"],
                    "offsets": thing_only(offsets, is_thing, "float32"),
                    "features": thing_only(features, is_thing, "float16"),
                },
                n_points=n,
                counts={"volumes": 1, "points": n, "thing_points": int(is_thing.sum())},
            )
