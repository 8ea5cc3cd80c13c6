"""What one labelling run is asked to do: :class:`LabelRequest`, shared by the flows, ``dsnet label``,
``dsnet demo`` and the scheduled deployment of ``dsnet serve``.

The command-line settings that shape the stages (k, stride, checkpoint, clusterer, pose
estimation) become per-stage configs in exactly one place, :func:`stage_settings`.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, field_validator

from tasks.base import RunOptions
from tasks.methods import DEFAULT_METHOD, get_pipeline
from tasks.pipeline import Pipeline


class LabelRequest(BaseModel):
    """One labelling run.

    Attributes:
        data: the log's root (any registered format).
        root: the run store (a folder or ``s3://bucket/prefix``).
        sequences: sequences to label (None: every sequence of the log).
        format: the log's format name, or ``auto`` to detect it.
        reader_options: keyword options of the format's reader (``{"topic": "/points"}``,
            ``{"sweeps": True}``); recorded in the run config so every stage opens the log alike.
        method: the method (:data:`tasks.methods.METHODS`) and ``method_options`` its factory's options.
        stages: per-stage config overrides (``{"align": {"scans": 2}}``).
        options: run-level policy (error handling, block size, locks).
        from_stage: recompute this stage and everything downstream.
        until: stop after this stage (default: run every stage).
        force: recompute every stage.
        storage_options: fsspec options of the run store.
    """

    model_config = ConfigDict(extra="forbid")

    data: str
    root: str
    sequences: list[str] | None = None
    format: str = "auto"
    reader_options: dict[str, Any] = Field(default_factory=dict)
    method: str = DEFAULT_METHOD
    method_options: dict[str, Any] = Field(default_factory=dict)
    stages: dict[str, dict[str, Any]] = Field(default_factory=dict)
    options: RunOptions = Field(default_factory=RunOptions)
    from_stage: str | None = None
    until: str | None = None
    force: bool = False
    storage_options: dict[str, Any] = Field(default_factory=dict)

    @field_validator("sequences")
    @classmethod
    def _plain_sequence_names(cls, value: list[str] | None) -> list[str] | None:
        from storage.errors import StoreError
        from storage.names import check_plain_name

        for name in value or []:
            try:
                check_plain_name(name)
            except StoreError as exc:
                raise ValueError(str(exc)) from exc
        return value

    def pipeline(self) -> Pipeline:
        """The method's stages. Raises ValueError for an unknown method or stage name.

        DS-Net's temporal association, unless ``method_options`` names it: tracking at k = 1 (volumes
        share no frame, so stitching could only hand out fresh ids), stitching for k > 1.
        """
        options = dict(self.method_options)
        if self.method in ("dsnet", "dpls") and options.get("temporal", "auto") == "auto":
            scans = int(self.stages.get("align", {}).get("scans", 1))
            options["temporal"] = "track" if scans == 1 else "stitch"
        elif options.get("temporal") == "auto":
            del options["temporal"]  # the method's own default
        pipeline = get_pipeline(self.method, **options)
        for name in (self.from_stage, self.until, *self.stages):
            pipeline.check_stage(name)
        return pipeline

    def order(self, pipeline: Pipeline) -> list[str]:
        """The stages this run executes, in order."""
        return pipeline.until(self.until)

    def forced(self, pipeline: Pipeline) -> set[str]:
        """The stages this run recomputes whatever their manifests say."""
        if self.force:
            return set(pipeline.names())
        if self.from_stage:
            return {self.from_stage, *pipeline.downstream_of(self.from_stage)}
        return set()

    def open_log(self):
        """The log's reader, opened with the request's format and reader options.

        Raises:
            DataFormatError: unknown format, nothing detected, or an option the reader lacks.
        """
        from dsnet_core.io.formats import open_log

        return open_log(self.data, self.format, self.reader_options)

    def stage_configs(self, pipeline: Pipeline, names: list[str] | None = None) -> dict[str, dict[str, Any]]:
        """The configs the run records for ``names`` (default: every stage of the pipeline): the
        request's overrides, and ingest's ``grid`` from the model card of infer's checkpoint (the
        bundled model for align's k when none is named) unless the request sets it.

        Raises:
            CheckpointError: the named checkpoint has no model card.
        """
        names = pipeline.names() if names is None else names
        out = {name: dict(self.stages.get(name, {})) for name in names}
        if "ingest" in out and "grid" not in out["ingest"]:
            grid = None
            if "infer" in pipeline:
                grid = model_grid(self.stages.get("infer", {}), self.stages.get("align", {}))
            elif "dpls" in pipeline:
                grid = dpls_model_grid(self.stages.get("dpls", {}))
            elif "most" in pipeline:
                grid = most_model_grid(self.stages.get("most", {}))
            if grid is not None:
                out["ingest"]["grid"] = grid
        return out

    def dataset_name(self) -> str:
        """A short name of the log (its folder's name), for artifact keys."""
        return str(self.data).rstrip("/").rsplit("/", 1)[-1]


def model_grid(infer: dict[str, Any], align: dict[str, Any]) -> dict[str, list[float]] | None:
    """The grid bounds of the model an infer config names (the bundled model for align's k when it
    names none); None when there is no bundled model for that k."""
    from dsnet_core.model.bundle import bundled_checkpoint
    from dsnet_core.model.checkpoint import read_card

    path = infer.get("checkpoint") or bundled_checkpoint(int(align.get("scans", 1)))
    if path is None:
        return None
    grid = read_card(path).config.grid
    return {"min_bound": list(grid.min_bound), "max_bound": list(grid.max_bound)}


def dpls_model_grid(dpls: dict[str, Any]) -> dict[str, list[float]] | None:
    """The grid bounds of the D-PLS model a ``dpls`` config names (the bundled one when it names
    none); None when no D-PLS model is bundled."""
    from dsnet_core.model.bundle import bundled_dpls_checkpoint
    from dsnet_core.model.checkpoint import read_card

    path = dpls.get("checkpoint") or bundled_dpls_checkpoint()
    if path is None:
        return None
    grid = read_card(path).config.grid
    return {"min_bound": list(grid.min_bound), "max_bound": list(grid.max_bound)}


def most_model_grid(most: dict[str, Any]) -> dict[str, list[float]] | None:
    """The grid bounds of the MOST model a ``most`` config names (the bundled one when it names
    none); None when no MOST model is bundled."""
    from dsnet_core.model.bundle import bundled_most_checkpoint
    from dsnet_core.most.checkpoint import read_most_card
    from dsnet_core.most.config import MostConfig

    path = most.get("checkpoint") or bundled_most_checkpoint(int(most.get("scans", 3)))
    if path is None:
        return None
    grid = MostConfig.from_dict(read_most_card(path).architecture).backbone.grid
    return {"min_bound": list(grid.min_bound), "max_bound": list(grid.max_bound)}


def parse_reader_options(pairs: list[str] | None, **named: Any) -> dict[str, Any]:
    """``["topic=/points", "sweeps=true"]`` -> ``{"topic": "/points", "sweeps": True}``: values are
    YAML scalars (``true``, ``5``, ``0.1``; anything else stays a string). ``named`` options (the
    command line's ``--topic``, ``--fixed-frame``) are added where not None; naming one both ways
    with different values is an error.

    Raises:
        ValueError: an entry without ``=`` or with an empty key.
    """
    import yaml

    out: dict[str, Any] = {}
    for pair in pairs or []:
        key, sep, value = pair.partition("=")
        key = key.strip().replace("-", "_")
        if not sep or not key:
            raise ValueError(f"--reader-option {pair!r}: expected KEY=VALUE (e.g. topic=/points)")
        try:
            parsed = yaml.safe_load(value) if value.strip() else ""
        except yaml.YAMLError:
            parsed = value
        out[key] = parsed if isinstance(parsed, str | int | float | bool) else value
    for key, value in named.items():
        if value is None:
            continue
        if key in out and out[key] != value:
            raise ValueError(f"reader option {key!r} given twice: {out[key]!r} and {value!r}")
        out[key] = value
    return out


def stage_settings(
    scans: int = 2,
    stride: int | None = None,
    checkpoint: str | None = None,
    clusterer: str | None = None,
    estimate_poses: bool = False,
    max_points: int | None = None,
    device: str | None = None,
    tta: int = 1,
    tta_flip: bool = False,
    equivariant: int | None = None,
    method: str = "dsnet",
    semantic_prior: str | None = None,
    prior_label_map: str | None = None,
) -> dict[str, dict[str, Any]]:
    """The per-stage configs of the command-line settings.

    For ``method="dpls"`` the checkpoint is the D-PLS instance network, the prior comes from
    ``semantic_prior`` (a folder of per-scan predictions, read through ``prior_label_map``) or, when
    none is given, from the bundled model's semantics, and clustering is DBSCAN unless ``clusterer``
    names another; TTA and equivariance are refused. The prior's settings are refused for the
    other methods.

    For ``method="most"``, ``scans`` is MOST's accumulation (the current scan and k − 1 past ones,
    stride 1) and ``align`` runs on single scans; the DS-Net-only settings (stride, clusterer,
    TTA, equivariance) are refused.

    Args:
        scans: k, scans per volume.
        stride: step between volumes (None: the stage's default).
        checkpoint: model checkpoint folder (None: the bundled model), resolved to an absolute path.
        clusterer: a clusterer kind (``dbscan``) or a JSON clusterer config.
        estimate_poses: estimate poses for sequences without them.
        max_points: ingest's per-frame point limit (None: its default).
        device: the model's torch device for infer (None: cpu).
        tta: yaw rotations averaged by infer (1: none); ``tta_flip`` adds their mirror images.
        equivariant: the n the checkpoint must have been trained with (None: whatever it has).
        method: the labelling method (:data:`tasks.methods.METHODS`).
        semantic_prior: D-PLS: the folder of per-scan prior files (:mod:`dsnet_core.io.prior`).
        prior_label_map: D-PLS: the prior files' label map, a bundled name or a YAML file.

    Raises:
        ValueError: ``clusterer`` is neither a kind nor valid JSON, or a setting the method lacks.
    """
    if method != "dpls":
        _refuse(
            method,
            {"--semantic-prior": bool(semantic_prior), "--prior-label-map": bool(prior_label_map)},
            "dpls",
        )
    if method == "dpls":
        return _dpls_settings(
            scans, stride, checkpoint, clusterer, estimate_poses, max_points, device, tta, tta_flip,
            equivariant, semantic_prior, prior_label_map,
        )  # fmt: skip
    if method == "most":
        return _most_settings(
            scans, stride, checkpoint, clusterer, estimate_poses, max_points, device, tta, tta_flip,
            equivariant,
        )  # fmt: skip
    stages: dict[str, dict[str, Any]] = {"align": {"scans": scans, **({"stride": stride} if stride else {})}}
    stages.update(_ingest_settings(estimate_poses, max_points))
    infer: dict[str, Any] = {}
    if checkpoint:
        infer["checkpoint"] = str(Path(checkpoint).expanduser().resolve())
    if device:
        infer["device"] = device
    if tta != 1 or tta_flip:
        infer.update(tta=tta, tta_flip=tta_flip)
    if equivariant is not None:
        infer["equivariant"] = equivariant
    if infer:
        stages["infer"] = infer
    if clusterer:
        stages["shift"] = {"clusterer": _clusterer_config(clusterer)}
    return stages


def _ingest_settings(estimate_poses: bool, max_points: int | None) -> dict[str, dict[str, Any]]:
    """Ingest's settings of the command line (every method shares ingest)."""
    ingest: dict[str, Any] = {"estimate_poses": True} if estimate_poses else {}
    if max_points is not None:
        ingest["max_points"] = max_points
    return {"ingest": ingest} if ingest else {}


def _refuse(method: str, refused: dict[str, bool], owner: str = "dsnet") -> None:
    """Raise ValueError naming every given flag of ``refused`` (flags of another method)."""
    bad = [flag for flag, given in refused.items() if given]
    if bad:
        raise ValueError(
            f"{', '.join(bad)}: not a setting of method {method} (it applies to --method {owner})"
        )


def _clusterer_config(clusterer: str) -> dict[str, Any]:
    """``--clusterer``: a kind (``dbscan``) or a JSON config. Raises ValueError for bad JSON."""
    try:
        return json.loads(clusterer) if clusterer.lstrip().startswith("{") else {"kind": clusterer}
    except json.JSONDecodeError as exc:
        raise ValueError(f"--clusterer is not valid JSON: {exc}") from None


def _dpls_settings(
    scans: int,
    stride: int | None,
    checkpoint: str | None,
    clusterer: str | None,
    estimate_poses: bool,
    max_points: int | None,
    device: str | None,
    tta: int,
    tta_flip: bool,
    equivariant: int | None,
    semantic_prior: str | None,
    prior_label_map: str | None,
) -> dict[str, dict[str, Any]]:
    """:func:`stage_settings` for D-PLS (see there)."""
    _refuse("dpls", {"--tta": tta != 1 or tta_flip, "--equivariant": equivariant is not None})
    if prior_label_map and not semantic_prior:
        raise ValueError(
            "--prior-label-map: names the label map of --semantic-prior files; give --semantic-prior DIR"
        )
    stages: dict[str, dict[str, Any]] = {"align": {"scans": scans, **({"stride": stride} if stride else {})}}
    stages.update(_ingest_settings(estimate_poses, max_points))
    prior: dict[str, Any] = {}
    if semantic_prior:
        prior = {"source": "user", "path": str(Path(semantic_prior).expanduser().resolve())}
        if prior_label_map:
            is_file = Path(prior_label_map).expanduser().is_file()
            prior["label_map"] = (
                str(Path(prior_label_map).expanduser().resolve()) if is_file else prior_label_map
            )
    if device:
        prior["device"] = device
    if prior:
        stages["prior"] = prior
    dpls: dict[str, Any] = {}
    if checkpoint:
        dpls["checkpoint"] = str(Path(checkpoint).expanduser().resolve())
    if device:
        dpls["device"] = device
    if dpls:
        stages["dpls"] = dpls
    stages["shift"] = {"clusterer": _clusterer_config(clusterer) if clusterer else {"kind": "dbscan"}}
    return stages


def _most_settings(
    scans: int,
    stride: int | None,
    checkpoint: str | None,
    clusterer: str | None,
    estimate_poses: bool,
    max_points: int | None,
    device: str | None,
    tta: int,
    tta_flip: bool,
    equivariant: int | None,
) -> dict[str, dict[str, Any]]:
    """:func:`stage_settings` for MOST (see there)."""
    _refuse(
        "most",
        {
            "--stride": stride not in (None, 1),
            "--clusterer": bool(clusterer),
            "--tta": tta != 1 or tta_flip,
            "--equivariant": equivariant is not None,
        },
    )
    stages: dict[str, dict[str, Any]] = {"align": {"scans": 1}}
    stages.update(_ingest_settings(estimate_poses, max_points))
    most: dict[str, Any] = {"scans": scans}
    if checkpoint:
        most["checkpoint"] = str(Path(checkpoint).expanduser().resolve())
    if device:
        most["device"] = device
    stages["most"] = most
    return stages
