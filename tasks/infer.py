"""Stage ``infer``: the DS-Net network on every volume of ``align``.

Per point: ``sem`` (uint8 train id), ``probs`` (softmax probabilities quantised to uint8,
``p = q / 255``: 20 bytes a point instead of 40 for float16, error at most 1/510 — enough for
confidences and review queues, not for calibration studies; fuse, refine's soft votes and the
report read the whole vector), ``offsets`` (float32 ×3, metres) and ``features`` (float16 ×32).
A 4D volume goes through the network as one cloud. Offsets and features are kept on predicted
thing points only (zeros elsewhere, which compress to almost nothing): ``shift`` reads them there
and nothing reads them on stuff (:func:`thing_only`); the labels do not change.

The widths of ``probs`` and ``features`` are the model's (its card's class map and instance
feature size), recorded in the plan; so is the card's class map, which every downstream stage
reads as the run's label map (:attr:`tasks.base.StageContext.label_map`).

The fingerprint holds the checkpoint's content digest (:func:`checkpoint_digest`: the model
card with its weights' sha256, and the shifting weights' sha256), so a new model reprocesses
``infer`` and everything downstream; the same model under another path also does (the path is
part of the config).
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from typing import Literal

import numpy as np
from pydantic import Field, model_serializer

from storage.contract import ArraySpec
from tasks.align import volume_scans
from tasks.base import CLASS_MAP, ItemResult, Plan, Stage, StageConfig, StageContext

log = logging.getLogger(__name__)


class InferConfig(StageConfig):
    """Model settings.

    Attributes:
        checkpoint: checkpoint folder; None = the bundled demo model.
        device: torch device (``"cpu"``, ``"cuda"``, ``"cuda:1"``).
        batch: volumes per forward pass.
        tta: test-time augmentation: semantic logits averaged over this many yaw rotations (offsets
            rotated back first; :mod:`dsnet_core.model.tta`); 1 = the plain forward.
        tta_flip: also average each rotation's mirror image (2 × ``tta`` passes).
        equivariant: the ``n`` of a C_n-equivariant checkpoint the run asks for (``--equivariant``):
            labelling refuses a checkpoint trained with another n; None takes the card's.
        argmax: ``labelled`` (default): a point's class is the argmax over the classes without
            "unlabelled"; ``all``: over every class, the reference DS-Net's rule (reproducing its
            published numbers with an imported checkpoint; points may then be labelled 0).
        match: ``auto`` (default): ``ground`` for a checkpoint trained on a stream rendered like a
            sensor (its card's stream has a sensor card), else ``none``; ``none``: the network
            reads the log's clouds as they are; ``ground``,
            ``remission``, ``both``: each cloud moved toward the sensor the model was trained on
            (its card's sensor reference, :mod:`dsnet_core.model.sensor_match`) before the network
            reads it: the ground under the origin to the training sensor's height, the remission
            onto the training quantiles by rank. The stored points and every later stage keep the
            log's frame.
    """

    checkpoint: str | None = None
    device: str = "cpu"
    batch: int = Field(1, ge=1, le=64)
    tta: int = Field(1, ge=1, le=64)
    tta_flip: bool = False
    equivariant: int | None = Field(None, ge=1)
    argmax: Literal["labelled", "all"] = "labelled"
    match: Literal["auto", "none", "ground", "remission", "both"] = "auto"

    @model_serializer(mode="wrap")
    def _defaults_unrecorded(self, handler):
        """The default rule and match are left out of the record, so runs made before the settings
        existed keep their fingerprint (and are not recomputed)."""
        data = handler(self)
        if data.get("argmax") == "labelled":
            data.pop("argmax")
        if data.get("match") == "auto":
            data.pop("match")
        return data


def _check_device(device: str) -> None:
    """Refuse a device this machine lacks, before any block runs.

    Raises:
        ConfigError: not a torch device, or a CUDA device without CUDA.
    """
    import torch

    from dsnet_core.errors import ConfigError

    try:
        dev = torch.device(device)
    except (RuntimeError, ValueError) as exc:
        raise ConfigError(f"--device {device!r} is not a torch device ({exc})") from None
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise ConfigError(f"--device {device}: this machine has no CUDA device (torch {torch.__version__})")


def check_inputs(ctx: StageContext, spec, checkpoint) -> None:
    """Refuse a sequence that lacks an input channel the model reads (``ingest`` recorded each
    frame's source intensity convention; ``none`` = no intensity channel).

    Raises:
        MissingInputError: one line naming the log, the sequence and the input.
    """
    from dsnet_core.model.inputs import check_log_inputs

    if spec.needs_remission is None:
        return
    column = ctx.frames.column("intensity_convention").to_pylist()
    conventions = {c for c in column if c is not None}
    for convention in sorted(conventions):
        check_log_inputs(spec, ctx.run.data, ctx.sequence, convention, str(checkpoint))


def model_meta(path, card) -> dict:
    """The plan facts of a model stage: the checkpoint folder, ``<folder>@<weights sha256[:12]>`` (the
    report's model card) and the card's class map (the run's label map downstream)."""
    return {
        "checkpoint": str(path),
        "model_card": f"{path.name}@{card.weights_sha256[:12]}",
        CLASS_MAP: card.class_map,
    }


def quantise_probs(probs: np.ndarray) -> np.ndarray:
    """float ``(N, C)`` probabilities in [0, 1] → uint8 ``round(p * 255)`` (in torch: numpy's
    float16 conversions are several times slower)."""
    import torch

    from dsnet_core.model.inference import quantise

    return quantise(torch.from_numpy(np.ascontiguousarray(probs))).numpy()


def thing_only(values: np.ndarray, is_thing: np.ndarray, dtype: str) -> np.ndarray:
    """Per-point ``values`` ``(N, ...)`` as a new ``dtype`` array with the rows of non-thing points
    zeroed (``is_thing`` ``(N,) bool``): what ``shift`` reads of offsets and features, stored small."""
    out = np.array(values, dtype=dtype, copy=True)
    out[~is_thing] = 0
    return out


def dequantise_probs(q: np.ndarray) -> np.ndarray:
    """uint8 ``(N, C)`` → float32 probabilities ``q / 255``."""
    return np.asarray(q, np.float32) / np.float32(255.0)


class InferStage(Stage):
    name = "infer"
    upstream = ("align",)
    version = "1"
    Config = InferConfig
    item = "volume"
    arrays = (
        ArraySpec("sem", "uint8", doc="predicted train id (argmax over 1..C-1)"),
        ArraySpec(
            "probs",
            "uint8",
            trailing=("classes",),
            doc="softmax probabilities quantised to uint8: p = q / 255 (abs error <= 1/510)",
        ),
        ArraySpec(
            "offsets",
            "float32",
            trailing=(3,),
            doc="point -> instance centre, metres, on predicted thing points; 0 on stuff (never read)",
            codec="shuffle-lz4",
        ),
        ArraySpec(
            "features",
            "float16",
            trailing=("features",),
            doc="instance features for shifting on predicted thing points; 0 on stuff (never read)",
        ),
    )

    @staticmethod
    def checkpoint(ctx: StageContext):
        """The checkpoint folder: the configured one, else the bundled model for align's k."""
        from dsnet_core.checkpoints import DSNET

        return DSNET.resolve(ctx.config.checkpoint, volume_scans(ctx))

    def inputs(self, ctx: StageContext) -> str:
        from dsnet_core.checkpoints import checkpoint_digest

        return "checkpoint:" + checkpoint_digest(self.checkpoint(ctx))

    def plan(self, ctx: StageContext) -> Plan:
        from dsnet_core.model.checkpoint import read_card

        _check_device(ctx.config.device)
        align = ctx.manifest("align")
        path = self.checkpoint(ctx).resolve()
        card = read_card(path)
        cfg = card.config
        want = ctx.config.equivariant
        if want is not None and want != cfg.equivariant:
            from dsnet_core.errors import ConfigError

            raise ConfigError(
                f"--equivariant {want}: checkpoint {path} was trained with --equivariant {cfg.equivariant}; "
                "label with its n, or train one with this n (dsnet train dsnet --equivariant N)"
            )
        check_inputs(ctx, cfg.input_spec, path)
        from dsnet_core.model.inference import sensor_match

        sensor_match(path, card, ctx.config.match)  # a card without a reference is refused before any block
        return Plan(
            n_items=align.n_items,
            max_points=int(align.plan["max_points"]),
            meta=model_meta(path, card),
            dims={"classes": cfg.num_classes, "features": cfg.ins_dim},
        )

    def run_block(self, ctx: StageContext, items: list[int]) -> Iterator[ItemResult]:
        from dsnet_core.labels import label_map_from_class_map
        from dsnet_core.model.inference import Predictor
        from dsnet_core.model.tta import TTAConfig

        label_map = label_map_from_class_map(ctx.plan[CLASS_MAP])
        predictor = Predictor.from_checkpoint(
            ctx.plan["checkpoint"],
            device=ctx.config.device,
            expect_label_map=label_map,
            tta=TTAConfig(rotations=ctx.config.tta, flip=ctx.config.tta_flip),
            argmax=ctx.config.argmax,
            match=ctx.config.match,
        )
        align = ctx.arrays("align")
        thing = label_map.is_thing()
        clouds = (align.read_item(i, ["points"])["points"] for i in items)
        # quantised and thing-only as they are stored (quantise_probs, thing_only), done in the predictor
        results = predictor.predict_stored_iter(clouds, thing, ctx.config.batch)
        for item, res in zip(items, results, strict=True):
            n = int(res.sem.shape[0])
            yield ItemResult(
                item,
                arrays={
                    "sem": res.sem.astype(np.uint8),
                    "probs": res.probs,
                    "offsets": res.offsets,
                    "features": res.features,
                },
                n_points=n,
                counts={"volumes": 1, "points": n, "thing_points": int(res.kept.sum())},
            )
