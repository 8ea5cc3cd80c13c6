"""DS-Net (k = 1) and 4D-DS-Net (k > 1): offsets → dynamic shifting → fusion → stitching across
volumes or tracking each frame's instances; C_n-equivariant networks (Eq-4D) through the same
stages. Trained semantic → instance head → shifting MLPs (:class:`dsnet_core.train.loop.Trainer`)."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

from dsnet_core import checkpoints as ckpt
from tasks.methods.base import (
    CLUSTERER_HELP,
    INGEST_KEYS,
    METHOD,
    MODEL,
    LabelSettings,
    Method,
    StepCallback,
    TemporalSettings,
    TrainOptions,
    absolute,
    align_settings,
    check_options,
    clusterer_config,
    grid_of,
    ingest_settings,
    option,
    refined,
    resolve_temporal,
)
from tasks.methods.dsnet_train import DsnetTrainOptions, train_dsnet

if TYPE_CHECKING:
    from tasks.pipeline import Pipeline


class DsnetSettings(TemporalSettings):
    """DS-Net's label settings: the clusterer, test-time augmentation, equivariance."""

    clusterer: str | None = option(None, f"{CLUSTERER_HELP} (default dynamic_shift).", METHOD)
    tta: int = option(1, "Average the semantics over N yaw rotations (1: off).", MODEL, ge=1, le=64)
    tta_flip: bool = option(False, "With --tta: their mirror images too.", MODEL)
    equivariant: int | None = option(None, "Require a C_n-equivariant checkpoint of this n.", MODEL, ge=1)
    match: Literal["auto", "none", "ground", "remission", "both"] = option(
        "auto",
        "Move each cloud toward the model's training sensor before the network reads it: ground "
        "height under the origin, remission quantiles by rank, or both; auto: ground for a model "
        "trained on a stream rendered like a sensor (--stream-like), else none (docs/sensor_match.md).",
        MODEL,
    )


class Dsnet(Method):
    name = "dsnet"
    title = "DS-Net (k = 1) / 4D-DS-Net (k ≥ 2)"
    default_scans = 2
    Settings = DsnetSettings
    stage_keys = INGEST_KEYS | {
        "scans": ("align.scans",),
        "stride": ("align.stride",),
        "checkpoint": ("infer.checkpoint",),
        "equivariant": ("infer.equivariant", "infer.checkpoint"),
        "device": ("infer.device",),
        "tta": ("infer.tta", "infer.tta_flip"),
        "tta_flip": ("infer.tta", "infer.tta_flip"),
        "clusterer": ("shift.clusterer",),
        "match": ("infer.match",),
    }
    TrainOptions = DsnetTrainOptions
    data_parallel = True
    adaptable = True
    checkpoints = ckpt.DSNET
    homes = ("tasks/methods/dsnet_train.py",)

    def pipeline(
        self, options: Mapping[str, Any] | None = None, stages: Mapping[str, Mapping[str, Any]] | None = None
    ) -> Pipeline:
        from tasks.infer import InferStage
        from tasks.methods.bottom_up import bottom_up

        check_options(self.name, options, ("temporal", "refine"))
        return refined(
            bottom_up(self.name, (InferStage(),), "infer", resolve_temporal(options, stages)), options
        )

    def scans(self, settings: LabelSettings) -> int:
        """``--scans``; without it, the k the checkpoint was trained (or adapted) at, as its card
        records it (an adapted k = 1 model is not fed 2-scan volumes), else :attr:`default_scans`."""
        if settings.scans is None and settings.checkpoint:
            found = card_scans(settings.checkpoint)
            if found is not None:
                return found
        return super().scans(settings)

    def stage_configs(self, settings: LabelSettings) -> dict[str, dict[str, Any]]:
        stages = align_settings(self.scans(settings), settings.stride) | ingest_settings(settings)
        infer: dict[str, Any] = {}
        if settings.checkpoint:
            infer["checkpoint"] = absolute(settings.checkpoint)
        elif settings.equivariant is not None:  # the bundled C_n model, where one is bundled
            from dsnet_core.checkpoints import DSNET_EQUIVARIANT

            kind = DSNET_EQUIVARIANT.get(settings.equivariant)
            found = None if kind is None else kind.bundled()
            if found is not None:
                infer["checkpoint"] = str(found)
        if settings.device:
            infer["device"] = settings.device
        if settings.tta != 1 or settings.tta_flip:
            infer.update(tta=settings.tta, tta_flip=settings.tta_flip)
        if settings.equivariant is not None:
            infer["equivariant"] = settings.equivariant
        if settings.match != "auto":
            infer["match"] = settings.match
        if infer:
            stages["infer"] = infer
        if settings.clusterer:
            stages["shift"] = {"clusterer": clusterer_config(settings.clusterer)}
        return stages

    def model_grid(self, stages: Mapping[str, Mapping[str, Any]]) -> dict[str, list[float]] | None:
        infer, align = stages.get("infer", {}), stages.get("align", {})
        path = infer.get("checkpoint") or self.bundled_checkpoint(int(align.get("scans", 1)))
        return None if path is None else grid_of(self.checkpoints.read_card(path).config.grid)

    def train(self, options: TrainOptions, on_step: StepCallback | None = None) -> str:
        assert isinstance(options, DsnetTrainOptions)
        return train_dsnet(self, options, on_step)


def card_scans(checkpoint: str | Path) -> int | None:
    """The k of a checkpoint's card: ``training_data.scans`` (trained, adapted), an import's kind
    (``dsnet`` 1, ``dsnet4d`` 2), or None (no card, or it says nothing)."""
    from dsnet_core.errors import CheckpointError
    from dsnet_core.model.card import card_json

    try:
        data = card_json(Path(checkpoint).expanduser()).get("training_data") or {}
    except CheckpointError:
        return None  # the stage config's own checks name a missing or broken card
    k = data.get("scans")
    if isinstance(k, int) and not isinstance(k, bool) and k >= 1:
        return k
    return {"dsnet": 1, "dsnet4d": 2}.get((data.get("imported") or {}).get("kind"))


DSNET = Dsnet()
