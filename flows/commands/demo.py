"""``dsnet demo``: synthetic log → label with the bundled model → export → score. Heavy imports
stay in the body so ``dsnet --help`` is instant."""

from __future__ import annotations

from pathlib import Path

import typer

from flows.commands import options as o
from flows.commands.common import errors_exit


def _default_method():
    from tasks.methods import get_method

    return [get_method()]


@o.with_label_settings(_default_method)
def demo(
    ctx: typer.Context,
    out: Path = typer.Option(
        Path("demo-out"), help="Folder for the log, the run store, predictions, scores."
    ),
    frames: int = typer.Option(10, min=1, help="Sweeps in the demo sequence."),
    seed: int = typer.Option(0, help="Seed of the synthetic log."),
    sensor: str = typer.Option("hdl64", help="LiDAR model: hdl64 or vlp32 (faster)."),
    settings: dict | None = None,
) -> None:
    """Generate a small synthetic log, label it with the default method's bundled model (or
    --checkpoint), export and score it; the default method's label settings are its options."""
    import json
    import shutil

    from dsnet_core.io.describe import summarize
    from dsnet_core.io.formats import open_log
    from flows.commands.describe import print_log_summary
    from flows.commands.eval import print_result, score_predictions
    from flows.commands.label import print_stage_table, run_label
    from flows.commands.synth import generate
    from flows.config import resolve
    from flows.export import export_semantickitti
    from tasks.methods import LabelSettings, get_method

    log, run, pred = out / "log", out / "run", out / "predictions"
    typer.echo(f"[1/5] generating a synthetic {sensor} log: 1 sequence × {frames} frames, seed {seed}")
    with errors_exit():
        generate(log, 1, frames, seed, sensor, 0, True)
    typer.echo(f"      wrote {log.resolve() / 'sequences' / '00'}")
    typer.echo("[2/5] reading it back through its log reader (every file checked)")
    with errors_exit():
        print_log_summary(summarize(open_log(log)))

    settings = dict(settings or {})
    with errors_exit():
        method = get_method()
        scans = method.scans(method.settings_of(LabelSettings(**settings)))
    checkpoint = settings.get("checkpoint")
    ckpt = _model(Path(checkpoint) if checkpoint else None, scans, out, log, run)
    if ckpt is None:
        return
    typer.echo(f"[3/5] labelling with k = {scans} ({'3D' if scans == 1 else '4D'} panoptic) into {run}")
    with errors_exit():
        config = resolve(
            settings={**settings, "scans": scans, "checkpoint": str(ckpt)}, given={"sequences": ["00"]}
        )
        request = config.request(data=str(log), root=str(run))
    summary = run_label(request)
    print_stage_table(summary)
    if any(r["action"] == "failed" for r in summary):
        raise typer.Exit(code=1)

    typer.echo(f"[4/5] exporting SemanticKITTI predictions to {pred}")
    shutil.rmtree(pred, ignore_errors=True)
    with errors_exit():
        exported = export_semantickitti(str(run), pred)
    typer.echo(f"      {exported.frames.get('00', 0)} label files")

    typer.echo("[5/5] scoring against the log's ground truth (PQ family, mIoU, LSTQ)")
    with errors_exit():
        result = score_predictions(log, pred, ["00"])
    print_result(result)
    scores = out / "scores.json"
    scores.write_text(json.dumps(result.to_dict(), indent=2) + "\n")
    typer.echo(
        f"PQ {100 * result.panoptic.pq:.1f}  LSTQ {100 * result.lstq.lstq:.1f}  ({result.frames} frames)"
    )
    typer.echo(
        f"outputs: log {log.resolve()}, run store {run.resolve()}, predictions {pred.resolve()}, "
        f"scores {scores.resolve()}"
    )
    if (run / "dashboard.html").exists():  # written by the label flow's score report
        typer.echo(f"dashboard {(run / 'dashboard.html').resolve()}")


def _model(checkpoint: Path | None, scans: int, out: Path, log: Path, run: Path) -> Path | None:
    """The checkpoint the demo labels with (the bundled one for k = ``scans`` by default), said;
    None, with what to do instead, when the package holds no model."""
    from dsnet_core.checkpoints import bundled_checkpoint, bundled_dir
    from dsnet_core.model.card import read_card

    ckpt = checkpoint if checkpoint is not None else bundled_checkpoint(scans)
    if ckpt is None:
        typer.echo(
            f"no bundled model: {bundled_dir(scans)} holds no trained checkpoint (a copy of the package "
            "without its model files?), so this demo stops "
            "after generating and checking the log. Label it with your own model:\n"
            f"  dsnet demo --out {out} --checkpoint PATH\n"
            f"  dsnet label {log} --run {run} --checkpoint PATH"
        )
        return None
    with errors_exit():
        card = read_card(ckpt)
    source = "bundled model" if checkpoint is None else "checkpoint"
    typer.echo(f"model: {source} {Path(ckpt).resolve()} (epochs {card.epochs or 'none'})")
    if not card.epochs:
        typer.secho(
            "      its model card records no training (random weights?): the scores below test the "
            "pipeline, they say nothing about a model",
            fg=typer.colors.YELLOW,
        )
    return Path(ckpt)
