"""MOST: modal object centres on a bird's-eye view of the cylinder backbone, PointSegMLP
membership, learned velocities; always tracked (its frames share no volume to stitch). Trained
``detect`` → ``member`` (:class:`dsnet_core.train.most.MostTrainer`)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any, Literal

from pydantic import Field

from dsnet_core import checkpoints as ckpt
from tasks.methods.base import (
    INGEST_KEYS,
    METHOD,
    LabelSettings,
    Method,
    StepCallback,
    TemporalSettings,
    TrainOptions,
    absolute,
    check_options,
    grid_of,
    ingest_settings,
    option,
    refined,
)
from tasks.methods.dsnet import DSNET
from tasks.methods.training import StepOptions

if TYPE_CHECKING:
    from tasks.pipeline import Pipeline

TRAIN_STAGES = ("detect", "member")


class MostTrainOptions(StepOptions):
    """Detection, segmentation and velocity (stage detect), then PointSegMLP (stage member);
    --init-from a DS-Net checkpoint starts the shared backbone ('bundled': DS-Net's single-scan
    model); data-parallel under torchrun."""

    epochs: str = Field("10", description="Epochs per stage: N for both, or 'detect=6,member=2'.")
    stage: Literal["detect", "member", "all"] = Field("all", description="detect | member | all.")
    scans: int = Field(3, ge=1, le=16, description="k: the current scan plus k-1 past ones.")
    preset: str = Field(
        "tiny",
        description="Backbone preset: tiny | small | paper | reference (width 32, the imported "
        "DS-Net's: with --init-from an import; slow on CPU) | cylinder3d.",
    )
    grid: str | None = Field(None, description="Cylinder cells 'ρ,φ,z' (default: the preset's).")


class MostSettings(TemporalSettings):
    """MOST's label settings: k counts the scan and its past ones; it reads every scan (stride 1)
    and tracks (temporal track)."""

    scans: int | None = option(None, "k: the scan and its k-1 past ones (default 3).", METHOD, ge=1, le=16)


class Most(Method):
    name = "most"
    title = "MOST (modal centres + PointSegMLP, tracked)"
    default_scans = 3
    Settings = MostSettings
    stage_keys = INGEST_KEYS | {
        "scans": ("most.scans",),
        "checkpoint": ("most.checkpoint",),
        "device": ("most.device",),
    }
    TrainOptions = MostTrainOptions
    data_parallel = True
    checkpoints = ckpt.MOST
    homes = ("tasks/most.py",)

    def pipeline(
        self, options: Mapping[str, Any] | None = None, stages: Mapping[str, Mapping[str, Any]] | None = None
    ) -> Pipeline:
        from tasks.align import AlignStage
        from tasks.ingest import IngestStage
        from tasks.most import MostStage
        from tasks.pipeline import Pipeline
        from tasks.score import ScoreStage
        from tasks.track import TrackStage

        check_options(self.name, options, ("temporal", "refine"))
        temporal = (options or {}).get("temporal", "track")
        if temporal not in ("track", "auto"):
            raise ValueError(
                f"method most associates over time by tracking only (--temporal track), not {temporal!r}"
            )
        model = MostStage()
        stages_ = (
            IngestStage(),
            AlignStage(),
            model,
            TrackStage(source=model.name),
            ScoreStage(labels="track"),
        )
        return refined(Pipeline(self.name, stages_, labels="track"), options)

    def options(self, settings: LabelSettings) -> dict[str, Any]:
        # tracking is MOST's only association: only refine is recorded
        return {} if settings.refine is None else {"refine": settings.refine}

    def stage_configs(self, settings: LabelSettings) -> dict[str, dict[str, Any]]:
        if settings.stride not in (None, 1):
            raise ValueError(
                "--stride: not a setting of method most (it reads every scan with its k-1 predecessors)"
            )
        if settings.temporal not in ("auto", "track"):
            raise ValueError(f"--temporal {settings.temporal}: method most tracks (--temporal track)")
        stages: dict[str, dict[str, Any]] = {"align": {"scans": 1}} | ingest_settings(settings)
        most: dict[str, Any] = {"scans": self.scans(settings)}
        if settings.checkpoint:
            most["checkpoint"] = absolute(settings.checkpoint)
        if settings.device:
            most["device"] = settings.device
        stages["most"] = most
        return stages

    def model_grid(self, stages: Mapping[str, Mapping[str, Any]]) -> dict[str, list[float]] | None:
        from dsnet_core.most.config import MostConfig

        most = stages.get("most", {})
        path = most.get("checkpoint") or self.bundled_checkpoint(int(most.get("scans", self.default_scans)))
        if path is None:
            return None
        return grid_of(MostConfig.from_dict(self.checkpoints.read_card(path).architecture).backbone.grid)

    def train(self, options: TrainOptions, on_step: StepCallback | None = None) -> str:
        from dataclasses import replace

        from dsnet_core.model.presets import get_preset
        from tasks.methods.dsnet_train import parse_grid

        assert isinstance(options, MostTrainOptions)
        # the options first, before torch and the trainer are imported (seconds on a loaded machine)
        epochs = options.epoch_counts(TRAIN_STAGES)
        if options.stage != "all" and not epochs[options.stage]:
            raise ValueError(
                f"--stage {options.stage} with --epochs {options.epochs!r} trains 0 epochs: name it (e.g. "
                f"--epochs {options.stage}=2)"
            )
        backbone = get_preset(options.preset)
        if options.grid:
            backbone = replace(backbone, grid=replace(backbone.grid, size=parse_grid(options.grid)))

        import torch

        from dsnet_core.most.config import MostConfig
        from dsnet_core.train import distributed
        from dsnet_core.train.most import MostTrainConfig, MostTrainer
        from dsnet_core.train.skeleton import config_from
        from tasks.methods.training import open_training_data

        torch.set_num_threads(options.threads)
        data = open_training_data(options)
        cfg = config_from(MostTrainConfig, options.model_dump(), epochs=epochs)
        start = options.start_from(DSNET, 1)  # the shared backbone is a DS-Net's
        try:
            trainer = MostTrainer(
                options.out, MostConfig(backbone=backbone), data.reader, data.sequences, data.val_reader,
                data.val_sequences, data.label_map, cfg, options.resume, backbone_from=start,
            )  # fmt: skip
            card = trainer.run(on_step=on_step if trainer.dist.is_main else None)
        finally:
            distributed.teardown()
        last = card.metrics[-1] if card.metrics else {}
        miou, recall = last.get("val_miou", float("nan")), last.get("val_det_recall", float("nan"))
        return (
            f"wrote MOST checkpoint {options.out.resolve()} (epochs {card.epochs}, val mIoU {miou:.4f}, "
            f"detection recall {recall:.3f})"
        )


MOST = Most()
