"""``dsnet config dump [--method M]``: a method's full default labelling config as YAML, the file
``dsnet label --config`` and ``dsnet serve --config`` take (:mod:`flows.config`)."""

from __future__ import annotations

import typer

from flows.commands.common import errors_exit

config = typer.Typer(
    name="config",
    help="Labelling configs: `dsnet config dump` prints the defaults `dsnet label --config` takes.",
    no_args_is_help=True,
)


@config.command()
def dump(
    method: str = typer.Option(
        None, "--method", help="The method whose defaults to print (default: the default one)."
    ),
) -> None:
    """Print a method's full default labelling config (every stage's settings) as YAML."""
    from flows.config import default_config

    with errors_exit():
        text = default_config(method).to_yaml()
    typer.echo(
        f"# dsnet label LOG --run R --config FILE; ingest.grid null: the model's grid\n{text}", nl=False
    )
