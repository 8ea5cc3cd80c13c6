"""``dsnet review export RUN --top N --out DIR``: the least confident frames, ready to correct."""

from __future__ import annotations

from pathlib import Path

import typer

from flows.commands.common import check_output, errors_exit

review = typer.Typer(
    help="The review loop: export the least confident frames of a run.", no_args_is_help=True
)


@review.command("export")
def export_review_command(
    root: str = typer.Argument(..., help="Run store root (folder or s3://…)."),
    top: int = typer.Option(10, "--top", help="How many frames (the least confident first)."),
    out: Path = typer.Option(..., "--out", help="Folder to write (SemanticKITTI layout + review.json)."),
) -> None:
    """Write the N least confident frames with their predicted labels (correct them, then
    ``dsnet train dsnet DIR --init-from CKPT --holdout 0.2 --patience 3``)."""
    from flows.review import export_review

    with errors_exit():
        check_output(out, "--out", "folder")
        rows = export_review(root, out, top)
    for r in rows:
        typer.echo(
            f"{r['sequence']}/{r['frame_id']}: score {r['score']:.3f} (semantic {r['semantic']:.3f}, "
            f"agreement {r['agreement']:.3f}, size {r['size']:.3f}, stitch {r['stitch']:.3f})"
        )
    typer.echo(f"wrote {len(rows)} frames to {out.resolve()}")
