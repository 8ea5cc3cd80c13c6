"""The options ``dsnet label``, ``serve`` and ``demo`` share: the run's own (typer ``Annotated``
types, grouped in ``--help`` by panel) and the methods' label settings, whose flags are made of each
method's settings model (:attr:`~tasks.methods.base.Method.Settings`: a field's description is its
help, its ``panel`` its group) by :func:`with_label_settings`, as ``dsnet train METHOD`` makes its
options of the trainer's. Nothing here names a method or one of their settings."""

from __future__ import annotations

import functools
import inspect
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Annotated, Any, Literal, get_args, get_origin

import typer

from flows.commands.common import FIXED_FRAME_HELP, FORMAT_HELP, READER_OPTION_HELP, TOPIC_HELP
from tasks.methods import DEFAULT_METHOD, METHODS

INPUT, METHOD, MODEL, RUN, SCALE = "Input", "Method", "Model", "Run", "Scale-out"

Format = Annotated[str, typer.Option("--format", help=FORMAT_HELP, rich_help_panel=INPUT)]
ReaderOption = Annotated[
    list[str] | None, typer.Option("--reader-option", help=READER_OPTION_HELP, rich_help_panel=INPUT)
]
Topic = Annotated[str | None, typer.Option("--topic", help=TOPIC_HELP, rich_help_panel=INPUT)]
FixedFrame = Annotated[
    str | None, typer.Option("--fixed-frame", help=FIXED_FRAME_HELP, rich_help_panel=INPUT)
]
MethodName = Annotated[
    str | None,
    typer.Option(
        "--method",
        help=f"The labelling method: {', '.join(METHODS)} (the README's method table; default "
        f"{DEFAULT_METHOD}).",
        rich_help_panel=METHOD,
    ),
]
Config = Annotated[
    Path | None,
    typer.Option(
        "--config",
        help="A YAML config (`dsnet config dump`, or a run folder's config.yaml to reproduce it); flags "
        "given here override it.",
        rich_help_panel=RUN,
    ),
]
Set = Annotated[
    list[str] | None,
    typer.Option(
        "--set",
        help="Override one config key, repeatable: STAGE.KEY=VALUE (infer.tta=2, shift.clusterer=dbscan) "
        "or options.KEY=VALUE; applied last.",
        rich_help_panel=RUN,
    ),
]
Until = Annotated[str | None, typer.Option(help="Stop after this stage (e.g. align).", rich_help_panel=RUN)]


def setting_fields(methods: Iterable[Any]) -> dict[str, list[tuple[Any, Any]]]:
    """Every label setting of ``methods`` (in their order), with the methods that take it and
    their field (``{"tta": [(DSNET, FieldInfo)], ...}``)."""
    out: dict[str, list[tuple[Any, Any]]] = {}
    for method in methods:
        for name, field in method.Settings.model_fields.items():
            out.setdefault(name, []).append((method, field))
    return out


def setting_help(takers: list[tuple[Any, Any]], every: int) -> str:
    """A setting's help: its description; the methods that take it where not all of them do; each
    method's own where their descriptions differ."""
    by_text: dict[str, list[str]] = {}
    for method, field in takers:
        by_text.setdefault(field.description or "", []).append(method.name)
    if len(by_text) == 1:
        text, names = next(iter(by_text.items()))
        return text if len(names) == every else f"{', '.join(names)}: {text}"
    return " ".join(f"{', '.join(names)}: {text}" for text, names in by_text.items())


def setting_parameter(name: str, field: Any, help: str) -> inspect.Parameter:
    """A typer option of one settings field (``tta_flip`` → ``--tta-flip``; a ``bool | None`` one
    ``--refine/--no-refine``), in the help panel its field names."""
    flag = "--" + name.replace("_", "-")
    panel = (field.json_schema_extra or {}).get("panel", METHOD)
    annotation = field.annotation
    if annotation is bool:
        decls = [f"{flag}/--no-{flag[2:]}" if field.default else flag]
    elif set(get_args(annotation)) == {bool, type(None)}:
        decls = [f"{flag}/--no-{flag[2:]}"]
    else:
        decls = [flag]
        annotation = cli_type(annotation)
    opt = typer.Option(field.default, *decls, help=help, rich_help_panel=panel)
    return inspect.Parameter(
        name, inspect.Parameter.POSITIONAL_OR_KEYWORD, annotation=annotation, default=opt
    )


def cli_type(annotation: Any) -> Any:
    """What typer parses for a field: a Literal as str (pydantic checks the value)."""
    if get_origin(annotation) is Literal:
        return str
    return annotation


def given(ctx: typer.Context, values: dict[str, Any]) -> dict[str, Any]:
    """Those of ``values`` given on the command line (or by the environment), not defaults."""
    taken = ("COMMANDLINE", "ENVIRONMENT", "PROMPT")  # by name: typer may carry its own click
    return {k: v for k, v in values.items() if getattr(ctx.get_parameter_source(k), "name", None) in taken}


def with_label_settings(methods: Callable[[], Iterable[Any]] | None = None):
    """Give a command the flags of the label settings of ``methods()`` (default: every registered
    method). The command takes ``ctx`` and ``settings``: the settings given on the command line, by
    name (those left at their defaults are left out, so a ``--config`` file keeps its values)."""

    def decorate(command: Callable[..., Any]) -> Callable[..., Any]:
        chosen = list(methods() if methods is not None else METHODS.values())
        fields = setting_fields(chosen)
        params = [setting_parameter(n, t[0][1], setting_help(t, len(chosen))) for n, t in fields.items()]
        own = [
            p for p in inspect.signature(command, eval_str=True).parameters.values() if p.name != "settings"
        ]

        @functools.wraps(command)
        def wrapper(ctx: typer.Context, **values: Any) -> Any:
            settings = given(ctx, {p.name: values.pop(p.name) for p in params})
            return command(ctx, **values, settings=settings)

        wrapper.__signature__ = inspect.Signature([*own, *params])  # type: ignore[attr-defined]
        return wrapper

    return decorate


RUN_KEYS = {"on_error": "on_error", "block_size": "block_size", "lock_wait": "lock_wait_s"}
"""Run option flags and the :class:`~tasks.base.RunOptions` keys they set."""


def run_given(ctx: typer.Context, values: dict[str, Any]) -> dict[str, Any]:
    """The run's own flags given on the command line, as :class:`~flows.config.LabelConfig` keys:
    ``format``, ``sequences`` (comma-separated), ``reader_options`` (``--reader-option``, ``--topic``,
    ``--fixed-frame``), ``options`` (:data:`RUN_KEYS`).

    Raises:
        ValueError: a malformed ``--reader-option``.
    """
    from flows.request import parse_reader_options

    picked = given(ctx, values)
    out: dict[str, Any] = {}
    if "format" in picked:
        out["format"] = picked["format"]
    if picked.get("sequences"):
        out["sequences"] = [s for s in picked["sequences"].split(",") if s]
    readers = parse_reader_options(
        picked.get("reader_option"), topic=picked.get("topic"), fixed_frame=picked.get("fixed_frame")
    )
    if readers:
        out["reader_options"] = readers
    options = {key: picked[flag] for flag, key in RUN_KEYS.items() if flag in picked}
    if options:
        out["options"] = options
    return out


def configured_request(
    ctx: typer.Context,
    config: Path | None,
    overrides: list[str] | None,
    method: str | None,
    settings: dict[str, Any] | None,
    run_values: dict[str, Any],
    **fields: Any,
):
    """The :class:`~flows.request.LabelRequest` of a command line: the method's defaults, the
    ``config`` file, the label ``settings`` and run flags given (``run_values``: :func:`run_given`),
    then the ``overrides`` (``--set``); ``fields`` are the request's own (``data``, ``root``, ...).

    Raises:
        ConfigError, ValueError: one line naming the bad key, flag or file.
    """
    from flows.config import read_config, resolve

    file = read_config(config) if config is not None else None
    resolved = resolve(
        file,
        source=f"--config {config}",
        method=method,
        settings=settings,
        given=run_given(ctx, run_values),
        sets=overrides,
    )
    return resolved.request(**fields)
