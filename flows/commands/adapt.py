"""``dsnet adapt LOG... --out CKPT``: self-train a model on unlabelled target logs (``docs/adapt.md``).

The options are :class:`tasks.adapt.AdaptOptions`' fields (their descriptions the help), as
``dsnet train`` builds its sub-commands from each method's options.
"""

from __future__ import annotations

import inspect
from pathlib import Path
from typing import Any

import typer

from flows.commands.common import errors_exit
from flows.commands.model_folder import interrupted_exit, writing_folder


def _parameter(name: str, field) -> inspect.Parameter:
    """A typer parameter of one AdaptOptions field (``logs`` the argument; ``--from`` by its alias)."""
    kind = inspect.Parameter.POSITIONAL_OR_KEYWORD
    if name == "logs":
        return inspect.Parameter(
            name, kind, annotation=list[Path], default=typer.Argument(..., help=field.description)
        )
    flag = "--" + (field.alias or name).replace("_", "-")
    annotation = field.annotation
    if annotation is bool:
        opt = typer.Option(field.default, f"{flag}/--no-{flag[2:]}")
    else:
        opt = typer.Option(... if field.is_required() else field.default, flag)
        if str(getattr(annotation, "__origin__", "")) == "typing.Literal":
            annotation = str
    opt.help = field.description
    return inspect.Parameter(name, kind, annotation=annotation, default=opt)


def adapt_command():
    """The ``dsnet adapt`` command function, its signature made of :class:`AdaptOptions`."""
    from tasks.adapt import AdaptOptions

    def adapt(**values: Any) -> None:
        with errors_exit(), interrupted_exit():
            options = AdaptOptions(**values)
            with writing_folder(options.out, "dsnet adapt"):
                line = _run(options)
        typer.echo(line)
        typer.echo(f"metrics table: {options.out.resolve() / 'metrics.csv'}")
        typer.echo(  # the k the student trained at (label's own default is k = 2)
            f"relabel: dsnet label LOG --run RUN --refine --scans {options.scans} "
            f"--checkpoint {options.out.resolve()}"
        )

    fields = AdaptOptions.model_fields
    adapt.__signature__ = inspect.Signature([_parameter(n, f) for n, f in fields.items()])
    adapt.__doc__ = inspect.getdoc(AdaptOptions)
    return adapt


def _run(options) -> str:
    """Adapt with logging and progress bars: labelling stages per round, then the student's steps."""
    import logging

    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from flows.commands.train import StepBars
    from tasks.adapt import run_adapt

    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(message)s")
    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn())
    loss = TextColumn("{task.fields[loss]}")
    with Progress(*columns, loss, TimeElapsedColumn(), console=Console(stderr=True)) as bar:
        tasks: dict = {}

        def on_label(r: int, what: str, done: int, total: int) -> None:
            if (r, what) not in tasks:
                tasks[r, what] = bar.add_task(f"round {r} {what}", total=max(total, 1), loss="")
            bar.update(tasks[r, what], completed=done, total=max(total, 1))

        return run_adapt(options, StepBars(bar), on_label)
