"""The options ``dsnet label``, ``serve`` and ``demo`` share, declared once (typer ``Annotated``
types, grouped in ``--help`` by panel), and the one place they become a
:class:`~tasks.methods.LabelSettings` (validated alike for every command)."""

from __future__ import annotations

from typing import Annotated

import typer

from flows.commands.common import FIXED_FRAME_HELP, FORMAT_HELP, READER_OPTION_HELP, TOPIC_HELP

INPUT, METHOD, MODEL, RUN, SCALE = "Input", "Method", "Model", "Run", "Scale-out"

Format = Annotated[str, typer.Option("--format", help=FORMAT_HELP, rich_help_panel=INPUT)]
ReaderOption = Annotated[
    list[str] | None, typer.Option("--reader-option", help=READER_OPTION_HELP, rich_help_panel=INPUT)
]
Topic = Annotated[str | None, typer.Option("--topic", help=TOPIC_HELP, rich_help_panel=INPUT)]
FixedFrame = Annotated[
    str | None, typer.Option("--fixed-frame", help=FIXED_FRAME_HELP, rich_help_panel=INPUT)
]
MaxPoints = Annotated[
    int | None,
    typer.Option(
        "--max-points", help="Refuse frames with more points (default 2,000,000).", rich_help_panel=INPUT
    ),
]
EstimatePoses = Annotated[
    bool,
    typer.Option(
        "--estimate-poses",
        help="KISS-ICP poses for sequences without poses.txt (the \\[odometry] extra; log poses win).",
        rich_help_panel=INPUT,
    ),
]
MethodName = Annotated[
    str,
    typer.Option("--method", help="dsnet, most or dpls (the README's method table).", rich_help_panel=METHOD),
]
Scans = Annotated[
    int | None,
    typer.Option(
        help="k: scans per 4D volume (dsnet, dpls: 1 = 3D, default 2); most: the scan and k-1 past ones "
        "(default 3).",
        rich_help_panel=METHOD,
    ),
]
Stride = Annotated[
    int | None, typer.Option(help="Step between volumes (default k-1).", rich_help_panel=METHOD)
]
Clusterer = Annotated[
    str | None,
    typer.Option(
        help="dynamic_shift (default), meanshift, dbscan, hdbscan, bfs, or a JSON config.",
        rich_help_panel=METHOD,
    ),
]
Temporal = Annotated[
    str,
    typer.Option(
        "--temporal",
        help="Sequence-wide ids: stitch (k > 1), track, or auto (track at k = 1, else stitch).",
        rich_help_panel=METHOD,
    ),
]
SemanticPrior = Annotated[
    str | None,
    typer.Option(
        "--semantic-prior",
        help="dpls: per-scan predictions of any network (ID.label or ID.npy in sequences/SEQ/"
        "predictions/ under DIR); default: the bundled model's semantics.",
        rich_help_panel=METHOD,
    ),
]
PriorLabelMap = Annotated[
    str | None,
    typer.Option(
        "--prior-label-map",
        help="dpls: label map of --semantic-prior, a bundled name or a YAML (default: the log's).",
        rich_help_panel=METHOD,
    ),
]
Checkpoint = Annotated[
    str | None,
    typer.Option(help="Model checkpoint folder (default: the bundled model).", rich_help_panel=MODEL),
]
Device = Annotated[
    str | None, typer.Option("--device", help="cpu (default), cuda or cuda:N.", rich_help_panel=MODEL)
]
Tta = Annotated[
    int,
    typer.Option("--tta", help="Average the semantics over N yaw rotations (1: off).", rich_help_panel=MODEL),
]
TtaFlip = Annotated[
    bool, typer.Option("--tta-flip", help="With --tta: their mirror images too.", rich_help_panel=MODEL)
]
Equivariant = Annotated[
    int | None,
    typer.Option(
        "--equivariant", help="Require a C_n-equivariant checkpoint of this n.", rich_help_panel=MODEL
    ),
]
Refine = Annotated[
    bool | None,
    typer.Option(
        "--refine/--no-refine",
        help="Refine the whole sequence offline (static-world vote, one class per track, tracks joined "
        "across gaps); default: the method's (docs/refine.md). Switching recomputes refine and score.",
        rich_help_panel=METHOD,
    ),
]
Until = Annotated[str | None, typer.Option(help="Stop after this stage (e.g. align).", rich_help_panel=RUN)]


def label_settings(
    scans=None,
    stride=None,
    checkpoint=None,
    clusterer=None,
    estimate_poses=False,
    max_points=None,
    device=None,
    tta=1,
    tta_flip=False,
    equivariant=None,
    semantic_prior=None,
    prior_label_map=None,
    temporal="auto",
    refine=None,
):
    """The command line's labelling settings, validated (:class:`~tasks.methods.LabelSettings`).

    Raises:
        pydantic.ValidationError: a value out of range (``--scans 0``), an unknown ``--temporal``
            or ``--device``.
    """
    from tasks.methods import LabelSettings

    return LabelSettings(
        scans=scans,
        stride=stride,
        checkpoint=checkpoint,
        clusterer=clusterer,
        estimate_poses=estimate_poses,
        max_points=max_points,
        device=device,
        tta=tta,
        tta_flip=tta_flip,
        equivariant=equivariant,
        semantic_prior=semantic_prior,
        prior_label_map=prior_label_map,
        temporal=temporal,
        refine=refine,
    )
