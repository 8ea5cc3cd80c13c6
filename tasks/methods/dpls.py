"""D-PLS: single-scan semantic priors (the user's files, or the bundled DS-Net's semantics)
aggregated into the volumes, the prior-conditioned instance network, clustering (DBSCAN by
default), majority vote over the prior's classes, then stitching or tracking as for DS-Net.
Trained on corrupted ground-truth priors (:class:`dsnet_core.train.dpls.DplsTrainer`)."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pydantic import Field

from dsnet_core import checkpoints as ckpt
from tasks.methods.base import (
    CLUSTERER_HELP,
    INGEST_KEYS,
    METHOD,
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
from tasks.methods.dsnet import DSNET
from tasks.methods.training import StepOptions

if TYPE_CHECKING:
    from tasks.pipeline import Pipeline


class DplsTrainOptions(StepOptions):
    """The prior-conditioned instance network on corrupted ground-truth priors, from a trained
    DS-Net (--init-from, default the bundled single-scan model); data-parallel under torchrun."""

    epochs: str = Field("6", description="Passes over the training volumes.")
    scans: int = Field(1, ge=1, le=16, description="Scans per 4D volume (the prior is aggregated too).")


class DplsSettings(TemporalSettings):
    """D-PLS's label settings: the clusterer and the semantic prior."""

    clusterer: str | None = option(None, f"{CLUSTERER_HELP} (default dbscan).", METHOD)
    semantic_prior: str | None = option(
        None,
        "Per-scan predictions of any network (ID.label or ID.npy in sequences/SEQ/predictions/ under "
        "DIR); default: the bundled model's semantics.",
        METHOD,
    )
    prior_label_map: str | None = option(
        None, "Label map of --semantic-prior, a bundled name or a YAML (default: the log's).", METHOD
    )


class Dpls(Method):
    name = "dpls"
    title = "D-PLS (prior-conditioned instances)"
    default_scans = 2
    Settings = DplsSettings
    stage_keys = INGEST_KEYS | {
        "scans": ("align.scans",),
        "stride": ("align.stride",),
        "checkpoint": ("dpls.checkpoint",),
        "device": ("prior.device", "dpls.device"),
        "clusterer": ("shift.clusterer",),
        "semantic_prior": ("prior.source", "prior.path", "prior.label_map"),
        "prior_label_map": ("prior.label_map",),
    }
    TrainOptions = DplsTrainOptions
    data_parallel = True
    checkpoints = ckpt.DPLS
    homes = ("tasks/dpls.py",)

    def pipeline(
        self, options: Mapping[str, Any] | None = None, stages: Mapping[str, Mapping[str, Any]] | None = None
    ) -> Pipeline:
        from tasks.dpls import DplsStage
        from tasks.methods.bottom_up import bottom_up
        from tasks.prior import PriorStage

        check_options(self.name, options, ("temporal", "refine"))
        model = DplsStage()
        temporal = resolve_temporal(options, stages)
        return refined(bottom_up(self.name, (PriorStage(), model), model.name, temporal), options)

    def stage_configs(self, settings: LabelSettings) -> dict[str, dict[str, Any]]:
        if settings.prior_label_map and not settings.semantic_prior:
            raise ValueError(
                "--prior-label-map: names the label map of --semantic-prior files; give --semantic-prior DIR"
            )
        stages = align_settings(self.scans(settings), settings.stride) | ingest_settings(settings)
        prior: dict[str, Any] = {}
        if settings.semantic_prior:
            prior = {"source": "user", "path": absolute(settings.semantic_prior)}
            if settings.prior_label_map:
                named = settings.prior_label_map
                prior["label_map"] = absolute(named) if Path(named).expanduser().is_file() else named
        dpls: dict[str, Any] = {}
        if settings.checkpoint:
            dpls["checkpoint"] = absolute(settings.checkpoint)
        if settings.device:
            prior["device"] = dpls["device"] = settings.device
        if prior:
            stages["prior"] = prior
        if dpls:
            stages["dpls"] = dpls
        kind = clusterer_config(settings.clusterer) if settings.clusterer else {"kind": "dbscan"}
        stages["shift"] = {"clusterer": kind}
        return stages

    def model_grid(self, stages: Mapping[str, Mapping[str, Any]]) -> dict[str, list[float]] | None:
        path = stages.get("dpls", {}).get("checkpoint") or self.bundled_checkpoint(1)
        return None if path is None else grid_of(self.checkpoints.read_card(path).config.grid)

    def train(self, options: TrainOptions, on_step: StepCallback | None = None) -> str:
        assert isinstance(options, DplsTrainOptions)
        epochs = options.epoch_counts(("dpls",))["dpls"]  # before torch and the trainer are imported

        import torch

        from dsnet_core.train import distributed
        from dsnet_core.train.dpls import DplsTrainConfig, DplsTrainer
        from dsnet_core.train.skeleton import config_from
        from tasks.methods.training import open_training_data

        torch.set_num_threads(options.threads)
        data = open_training_data(options)
        cfg = config_from(DplsTrainConfig, options.model_dump(), epochs=epochs)
        start = options.start_from(DSNET, 1) or DSNET.bundled_checkpoint(1)  # it starts from a DS-Net
        try:
            trainer = DplsTrainer(
                options.out, data.reader, data.sequences, data.val_reader, data.val_sequences,
                data.label_map, cfg, start, options.resume,
            )  # fmt: skip
            card = trainer.run(on_step=on_step if trainer.dist.is_main else None)
        finally:
            distributed.teardown()
        last = card.metrics[-1] if card.metrics else {}
        return (
            f"wrote checkpoint {options.out.resolve()} (epochs {card.epochs}, val offset L1 clean "
            f"{last.get('val_offset_l1_clean', float('nan')):.3f} m, corrupted prior "
            f"{last.get('val_offset_l1_corrupted', float('nan')):.3f} m)"
        )


DPLS = Dpls()
