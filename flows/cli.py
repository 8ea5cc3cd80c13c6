"""The ``dsnet`` command line. Heavy imports live inside the commands so ``--help`` is instant;
each command's body lives in :mod:`flows.commands`, and commands never import this module."""

from __future__ import annotations

import typer

from flows.commands.adapt import adapt_command
from flows.commands.config import config
from flows.commands.dashboard import dashboard
from flows.commands.demo import demo
from flows.commands.describe import describe
from flows.commands.eval import eval_command
from flows.commands.export import export
from flows.commands.import_checkpoint import import_checkpoint
from flows.commands.label import label
from flows.commands.review import review
from flows.commands.serve import serve
from flows.commands.status import status
from flows.commands.synth import synth
from flows.commands.train import register_methods, train

app = typer.Typer(
    name="dsnet",
    help="Resumable 3D/4D LiDAR panoptic auto-labelling (DS-Net, 4D-DS-Net) and benchmark scoring.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
app.command()(describe)
app.command()(synth)
app.command()(demo)
app.command(name="eval")(eval_command)
app.command()(label)
app.command()(status)
register_methods()
app.add_typer(train, name="train")
app.command(name="adapt")(adapt_command())
app.command()(export)
app.command()(dashboard)
app.command()(serve)
app.command(name="import-checkpoint")(import_checkpoint)
app.add_typer(review, name="review")
app.add_typer(config, name="config")


def main() -> None:
    app()


if __name__ == "__main__":
    main()
