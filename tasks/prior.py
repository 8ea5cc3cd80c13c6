"""Stage ``prior``: D-PLS's semantic prior, per point of every volume of ``align``.

Single-scan semantic predictions aggregated with the points (paper Sec. 3.1): each scan's prior is
read (or predicted) in the scan's own point order and carried into the volume through align's
``source_frame`` / ``source_index``. Sources:

- ``user``: any network's predictions, one file per scan (:mod:`dsnet_core.io.prior`: ``.label``
  raw ids through ``label_map``, or ``.npy`` class probabilities). The fingerprint covers the
  files' names, sizes and modification times, as ingest's does for scans.
- ``model``: a DS-Net checkpoint's own semantic output on each single scan (default: the bundled
  single-scan model), so the method works without a user prior. The fingerprint holds its digest.

Per point: ``prior`` (class probabilities quantised to uint8 like infer's ``probs``) and ``sem``
(the prior's class, uint8 train id). The plan records the prior's class map; ``dpls`` checks it
against its checkpoint's. Switching source or files changes this stage's fingerprint only, so
``ingest`` and ``align`` are kept and ``prior`` and what follows it are recomputed.
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterator
from typing import Literal

import numpy as np
from pydantic import model_validator

from storage.contract import ArraySpec
from tasks.base import CLASS_MAP, ItemResult, Plan, Stage, StageConfig, StageContext
from tasks.infer import _check_device, quantise_probs


class PriorConfig(StageConfig):
    """Where the prior comes from.

    Attributes:
        source: ``user`` (files under ``path``) or ``model`` (a DS-Net checkpoint's semantics).
        path: the folder of the user's prior files (``dsnet label --semantic-prior DIR``).
        label_map: the user files' label map: a bundled name or a YAML file (``--prior-label-map``);
            None = the log's own ground-truth label map (its reader's).
        checkpoint: ``model`` source: a DS-Net checkpoint folder; None = the bundled single-scan model.
        device: ``model`` source: torch device.
    """

    source: Literal["user", "model"] = "model"
    path: str | None = None
    label_map: str | None = None
    checkpoint: str | None = None
    device: str = "cpu"

    @model_validator(mode="after")
    def _path_iff_user(self) -> PriorConfig:
        if (self.source == "user") != (self.path is not None):
            raise ValueError("a user prior needs its folder (path), a model prior takes none")
        return self


class PriorStage(Stage):
    name = "prior"
    upstream = ("align",)
    version = "1"
    Config = PriorConfig
    item = "volume"
    arrays = (
        ArraySpec(
            "prior",
            "uint8",
            trailing=("classes",),
            doc="the prior's class probabilities quantised to uint8: p = q / 255 (one-hot for labels)",
        ),
        ArraySpec("sem", "uint8", doc="the prior's class (train id): argmax over 1..C-1"),
    )

    @staticmethod
    def checkpoint(ctx: StageContext):
        from dsnet_core.checkpoints import DSNET

        return DSNET.resolve(ctx.config.checkpoint, 1)

    def inputs(self, ctx: StageContext) -> str:
        from dsnet_core.io.prior import find_prior

        if ctx.config.source == "model":
            from dsnet_core.checkpoints import checkpoint_digest

            return "checkpoint:" + checkpoint_digest(self.checkpoint(ctx))
        h = hashlib.blake2b(digest_size=16)
        for frame_id in ctx.frames["frame_id"].to_pylist():
            path = find_prior(ctx.config.path, ctx.sequence, frame_id)
            st = path.stat()
            h.update(f"{path.name}:{st.st_size}:{st.st_mtime_ns};".encode())
        return "prior-files:" + h.hexdigest()

    def plan(self, ctx: StageContext) -> Plan:
        from dsnet_core.labels import class_map_of

        align = ctx.manifest("align")
        meta: dict = {}
        if ctx.config.source == "model":
            from dsnet_core.model.checkpoint import read_card

            _check_device(ctx.config.device)
            path = self.checkpoint(ctx).resolve()
            card = read_card(path)
            meta = {"checkpoint": str(path), CLASS_MAP: card.class_map}
            classes = card.config.num_classes
        else:
            label_map = _files_label_map(ctx)
            meta = {CLASS_MAP: class_map_of(label_map)}
            classes = label_map.num_classes
        return Plan(
            n_items=align.n_items,
            max_points=int(align.plan["max_points"]),
            meta=meta,
            dims={"classes": classes},
        )

    def run_block(self, ctx: StageContext, items: list[int]) -> Iterator[ItemResult]:
        from dsnet_core.io.prior import prior_classes

        frame_prior = self._frame_source(ctx)
        values = ctx.frame_values()
        cache: dict[int, np.ndarray] = {}  # the frames a volume shares with the next

        def prior_of(f: int) -> np.ndarray:
            if f not in cache:
                cache[f] = frame_prior(f)
            return cache[f]

        for item in items:
            for f in set(cache) - set(values.windows[item]):
                del cache[f]
            probs, n = values.gather(item, prior_of, np.float32)
            if probs is None:
                probs = np.zeros((0, len(ctx.plan[CLASS_MAP]["class_names"])), np.float32)
            sem = prior_classes(probs)
            yield ItemResult(
                item,
                arrays={"prior": quantise_probs(probs), "sem": sem.astype(np.uint8)},
                n_points=n,
                counts={"volumes": 1, "points": n},
            )

    def _frame_source(self, ctx: StageContext):
        """frame index → float32 ``(N_f, C)`` prior in the scan's point order."""
        frames = ctx.frames.to_pydict()
        row = {int(i): r for r, i in enumerate(frames["index"])}
        if ctx.config.source == "user":
            from dsnet_core.io.prior import find_prior, read_prior

            label_map = _files_label_map(ctx)

            def from_file(f: int) -> np.ndarray:
                r = row[f]
                path = find_prior(ctx.config.path, ctx.sequence, frames["frame_id"][r])
                return read_prior(path, int(frames["n_points"][r]), frames["source_path"][r], label_map)

            return from_file
        from dsnet_core.labels import label_map_from_class_map
        from dsnet_core.model.inference import Predictor

        predictor = Predictor.from_checkpoint(
            ctx.plan["checkpoint"],
            device=ctx.config.device,
            expect_label_map=label_map_from_class_map(ctx.plan[CLASS_MAP]),
        )
        reader = ctx.reader
        refs = reader.frames(ctx.sequence)

        def from_model(f: int) -> np.ndarray:
            return predictor.predict(reader.scan(refs[f])).probs.astype(np.float32)

        return from_model


def _files_label_map(ctx: StageContext):
    """The label map of the user's prior files: the configured one, else the log's own.

    Raises:
        ConfigError: none configured and the log's format has no label map.
    """
    from dsnet_core.errors import ConfigError
    from dsnet_core.labels import load_label_map

    if ctx.config.label_map is not None:
        return load_label_map(ctx.config.label_map)
    if ctx.reader.label_map is None:
        raise ConfigError(
            f"the log {ctx.run.data} has no label map of its own: name the prior files' one "
            "(--prior-label-map NAME|YAML)"
        )
    return ctx.reader.label_map
