"""``dsnet eval``: a drop-in scorer for any SemanticKITTI-layout predictions folder, and for the
labels of a nuScenes log against its own Panoptic nuScenes ground truth (:mod:`.eval_nuscenes`).

Heavy imports live in the command body so ``dsnet --help`` stays instant.
"""

from __future__ import annotations

from pathlib import Path

import typer

from flows.commands.common import errors_exit, fail


def eval_command(
    gt: Path = typer.Option(
        ...,
        "--gt",
        help="Ground-truth root: SemanticKITTI (sequences/SS/labels/*.label) or a nuScenes log "
        "(Panoptic nuScenes ground truth, scored in the nuScenes metrics).",
    ),
    pred: Path = typer.Option(
        ...,
        "--pred",
        help="Prediction root: .label files in sequences/SS/predictions/, or for a nuScenes log also the "
        "results of `dsnet export --format nuscenes` (panoptic/<split>/).",
    ),
    sequences: str = typer.Option(
        None,
        help="Comma-separated sequences or scenes (default: every sequence with both ground truth and "
        "predictions; nuScenes: all).",
    ),
    data_config: Path = typer.Option(
        None,
        "--data-config",
        help="SemanticKITTI-style label YAML (default: the bundled semantic-kitti); for a nuScenes log, "
        "the model's label map, mapped to nuScenes classes through package data.",
    ),
    split: str = typer.Option(
        None, "--split", help="nuScenes results: the split folder (default: the only one)."
    ),
    min_points: int = typer.Option(
        None, "--min-points", min=0, help="Minimum segment size (default: config's, 50)."
    ),
    mode: str = typer.Option("official", help="official (benchmark-exact) or corrected."),
    json_out: Path = typer.Option(None, "--json", help="Also write the scores to this JSON file."),
) -> None:
    """Score predictions against ground truth: PQ family, mIoU and LSTQ, paired by file name; for a
    nuScenes log, the Panoptic nuScenes metrics (PQ family with min points 15, LSTQ, PAT) over all 16
    challenge classes and over those the model's classes can express."""
    from dsnet_core.io.nuscenes_reader import find_versions

    if json_out is not None and json_out.is_dir():  # before scoring, not after
        fail(f"--json {json_out}: is a folder; name a file (e.g. {json_out / 'scores.json'})")
    if (pred / "run.json").is_file():
        fail(f"--pred {pred}: a run store, not predictions: write them with `dsnet export {pred} --out DIR`, "
             "then --pred DIR")  # fmt: skip
    if find_versions(gt):  # a nuScenes log (v1.0-*/ tables)
        return _eval_nuscenes(gt, pred, sequences, data_config, split, json_out)
    with errors_exit():
        result = score_predictions(
            gt,
            pred,
            sequences.split(",") if sequences else None,
            data_config,
            min_points,
            mode,
            progress=True,
        )
    print_result(result)
    if json_out is not None:
        import json

        json_out.parent.mkdir(parents=True, exist_ok=True)
        json_out.write_text(json.dumps(result.to_dict(), indent=2) + "\n")
        typer.echo(f"wrote {json_out}")


def _eval_nuscenes(gt, pred, sequences, data_config, split, json_out) -> None:
    from flows.commands.eval_nuscenes import print_nuscenes, score_nuscenes

    with errors_exit():
        scorer = score_nuscenes(gt, pred, sequences.split(",") if sequences else None, data_config, split)
    print_nuscenes(scorer)
    if json_out is not None:
        import json

        json_out.parent.mkdir(parents=True, exist_ok=True)
        json_out.write_text(json.dumps(scorer.summary(), indent=2) + "\n")
        typer.echo(f"wrote {json_out}")


def score_predictions(
    gt: Path,
    pred: Path,
    sequences: list[str] | None = None,
    data_config: Path | None = None,
    min_points: int | None = None,
    mode: str = "official",
    progress: bool = False,
):
    """Score a predictions folder against a ground-truth folder → ``EvalResult``.

    Args:
        sequences: sequences to score (default: every sequence with both ground truth and
            predictions, which the progress line names).
        data_config: SemanticKITTI-style label YAML (default: the bundled semantic-kitti).

    Raises:
        DsnetError: a missing or mismatched file (named); ValueError: bad settings.
    """
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from dsnet_core.labels import load_label_map
    from dsnet_core.metrics.evaluator import PanopticEvaluator
    from dsnet_core.metrics.pairing import common_sequences, iter_pairs, pair_label_files

    label_map = load_label_map(data_config or "semantic-kitti")
    seqs = [s for s in sequences if s.strip()] if sequences else common_sequences(gt, pred)
    if not seqs:
        raise ValueError(
            f"no sequence has both ground truth ({gt}/sequences/SS/labels) and predictions "
            f"({pred}/sequences/SS/predictions); name them with --sequences"
        )
    if not sequences and progress:
        Console(stderr=True).print(
            f"scoring sequences {', '.join(seqs)} (those with ground truth and predictions)"
        )
    if min_points is not None and min_points < 0:
        raise ValueError(f"min_points must be >= 0, got {min_points}")
    ev = PanopticEvaluator(
        label_map, min_points=min_points, mode=mode, keep_rows=False, ignore=label_map.ignore
    )
    pairs = pair_label_files(gt, pred, seqs, label_map)  # raw ids the map does not know are refused
    columns = (TextColumn("scoring"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn())
    with Progress(*columns, console=Console(stderr=True), transient=True, disable=not progress) as bar:
        task = bar.add_task("frames", total=len(pairs))
        for pair, g, p in iter_pairs(pairs):
            ev.add(g, p, frame=pair.frame, sequence=pair.sequence)
            bar.advance(task)
    return ev.result()


def print_result(result) -> None:
    """Every registered metric's values (the official means, then the others, e.g. the means over
    the classes present), then the per-class values, as tables."""
    from flows.commands.eval_print import print_scores

    print_scores(
        f"panoptic scores ({result.frames} frames, mode: {result.mode})", result.values, result.classes
    )
