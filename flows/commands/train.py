"""``dsnet train METHOD DATA --out CKPT …``: one sub-command per registered method, whose options are
its trainer's (:attr:`~tasks.methods.base.Method.TrainOptions`, a pydantic model: each field an
option, its description the help). Nothing here names a method.

Under ``torchrun --nproc_per_node N -m flows.cli train dsnet …`` a method that trains data-parallel
runs one process per GPU; rank 0 alone shows progress and writes the checkpoint.
"""

from __future__ import annotations

import inspect
import os
from pathlib import Path
from typing import Any

import typer

from flows.commands.common import errors_exit
from flows.commands.model_folder import interrupted_exit, writing_folder

train = typer.Typer(
    name="train",
    help="Train a method's network on a labelled log (resumable; every epoch a checkpoint).",
    no_args_is_help=True,
)


def _parameter(name: str, field) -> inspect.Parameter:
    """A typer parameter of one TrainOptions field (``data`` is the argument, the rest options)."""
    kind = inspect.Parameter.POSITIONAL_OR_KEYWORD
    annotation = field.annotation
    if annotation is bool:  # a flag; its negation only where it is on by default
        flag = f"--{name.replace('_', '-')}"
        opt = typer.Option(field.default, f"{flag}/--no-{flag[2:]}" if field.default else flag)
    elif name == "data":
        return inspect.Parameter(
            name, kind, annotation=Path | None, default=typer.Argument(None, help=field.description)
        )
    else:
        required = field.is_required()
        default = ... if required else field.default
        opt = typer.Option(default, f"--{name.replace('_', '-')}")
        annotation = _cli_type(annotation)
    opt.help = field.description
    return inspect.Parameter(name, kind, annotation=annotation, default=opt)


def _cli_type(annotation: Any) -> Any:
    """What typer parses for a field: Literal and constrained types as their base (pydantic checks)."""
    origin = getattr(annotation, "__origin__", None)
    if origin is not None and str(origin) == "typing.Literal":
        return str
    return annotation


def method_command(method):
    """The ``dsnet train <method>`` command of ``method`` (a :class:`~tasks.methods.base.Method`)."""

    def command(**values: Any) -> None:
        from tasks.methods.resume import check_train_resume

        with errors_exit(), interrupted_exit():
            options = method.TrainOptions(**values)
            if int(os.environ.get("WORLD_SIZE", "1")) > 1 and not method.data_parallel:
                raise ValueError(
                    f"{method.name} trains in one process: run it without torchrun (or --nproc_per_node 1)"
                )
            options.check_paths()  # before torch and the trainer are imported
            with writing_folder(options.out, f"dsnet train {method.name}"):
                check_train_resume(options)
                line = _run(method, options)
        if int(os.environ.get("RANK", "0")) == 0:  # under torchrun, the final lines from rank 0 only
            typer.echo(line)
            typer.echo(f"metrics table: {options.out.resolve() / 'metrics.csv'}")

    fields = method.TrainOptions.model_fields
    command.__signature__ = inspect.Signature([_parameter(n, f) for n, f in fields.items()])
    command.__doc__ = f"Train {method.title}: {inspect.getdoc(method.TrainOptions) or ''}"
    return command


def _run(method, options) -> str:
    """Train with logging and progress bars on the main process (rank 0 under torchrun)."""
    import logging

    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    rank = int(os.environ.get("RANK", "0"))
    world = int(os.environ.get("WORLD_SIZE", "1"))
    tag = f" rank {rank}" if world > 1 else ""
    level = logging.INFO if rank == 0 else logging.WARNING
    logging.basicConfig(level=level, format=f"%(asctime)s{tag} %(levelname)s %(message)s")
    if rank != 0:
        return method.train(options)
    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn())
    loss = TextColumn("{task.fields[loss]}")
    with Progress(*columns, loss, TimeElapsedColumn(), console=Console(stderr=True)) as bar:
        return method.train(options, StepBars(bar))


class StepBars:
    """A training's step callback: one progress bar per stage and epoch, shown at ``0/steps``
    before the epoch's first step (``start``) and advanced after every step."""

    def __init__(self, bar) -> None:
        self.bar, self.tasks = bar, {}

    def start(self, stage: str, epoch: int, steps: int) -> None:
        if (stage, epoch) not in self.tasks:
            self.tasks[stage, epoch] = self.bar.add_task(f"{stage} epoch {epoch}", total=steps, loss="")

    def __call__(self, stage: str, epoch: int, step: int, total: int, value: float) -> None:
        self.start(stage, epoch, total)
        self.bar.update(self.tasks[stage, epoch], completed=step, total=total, loss=f"loss {value:.4f}")


def register_methods() -> None:
    """One sub-command per method of the registry (:data:`tasks.methods.METHODS`)."""
    from tasks.methods import METHODS

    for method in METHODS.values():
        command = method_command(method)
        train.command(name=method.name, help=command.__doc__)(command)
