"""One way to configure a labelling run: a YAML config (:class:`LabelConfig`), dotted overrides
(``--set infer.tta=2``) and the defaults it starts from (``dsnet config dump``).

A run's settings come in four layers, each over the one before: the method's defaults, the
``--config`` file, the flags given on the command line (a method's label settings,
:attr:`~tasks.methods.base.Method.Settings`, and the run's own: ``--format``, ``--block-size``, ...),
then ``--set`` overrides. A flag overrides the stage keys its method says it writes
(:attr:`~tasks.methods.base.Method.stage_keys`). Every layer is checked as it is laid: an unknown key
or a bad value is one :class:`~dsnet_core.errors.ConfigError` line naming the key and where it came
from, before any server starts. The run folder keeps the resolved config as ``config.yaml``
(:func:`resolved_config`), which ``--config`` takes back to reproduce the run.
"""

from __future__ import annotations

import copy
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from dsnet_core.errors import ConfigError
from tasks.base import RunOptions
from tasks.methods import DEFAULT_METHOD, LabelSettings, Method, get_method
from tasks.pipeline import Pipeline

if TYPE_CHECKING:
    from flows.request import LabelRequest

CONFIG_FILE = "config.yaml"
"""The resolved config a run folder keeps beside ``run.json``."""


class LabelConfig(BaseModel):
    """What a labelling run is configured with, apart from its log and its run store.

    Attributes:
        method: the labelling method (:data:`tasks.methods.METHODS`).
        method_options: the options its pipeline is built with (``temporal``, ``refine``).
        format: the log's format name (``auto``: detect).
        reader_options: keyword options of the format's reader.
        sequences: sequences to label (None: every sequence of the log).
        stages: per stage, its config (checked by the stage's ``Config``).
        options: run-level policy (:class:`~tasks.base.RunOptions`).
    """

    model_config = ConfigDict(extra="forbid")

    method: str = DEFAULT_METHOD
    method_options: dict[str, Any] = Field(default_factory=dict)
    format: str = "auto"
    reader_options: dict[str, Any] = Field(default_factory=dict)
    sequences: list[str] | None = None
    stages: dict[str, dict[str, Any]] = Field(default_factory=dict)
    options: RunOptions = Field(default_factory=RunOptions)

    def request(self, **fields: Any) -> LabelRequest:
        """The labelling request of this config for ``fields`` (``data``, ``root``, ``until``, ...)."""
        from flows.request import LabelRequest

        return LabelRequest(**self.model_dump(), **fields)

    def to_yaml(self) -> str:
        """The config as YAML (keys in declaration order)."""
        import yaml

        return yaml.safe_dump(self.model_dump(mode="json"), sort_keys=False, allow_unicode=True)


SECTIONS = tuple(LabelConfig.model_fields)


def read_config(path: str | Path) -> dict[str, Any]:
    """A config file's mapping (any subset of :class:`LabelConfig`'s keys).

    Raises:
        ConfigError: the file does not read, is not YAML, not a mapping, or has an unknown key.
    """
    import yaml

    try:
        data = yaml.safe_load(Path(path).expanduser().read_text())
    except OSError as exc:
        raise ConfigError(f"--config {path}: {exc.strerror or exc}") from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"--config {path}: not YAML ({str(exc).splitlines()[0]})") from None
    data = {} if data is None else data
    if not isinstance(data, dict):
        raise ConfigError(f"--config {path}: expected a mapping of {', '.join(SECTIONS)}")
    unknown = [k for k in data if k not in SECTIONS]
    if unknown:
        raise ConfigError(f"--config {path}: unknown key {unknown[0]!r} (keys: {', '.join(SECTIONS)})")
    return data


def parse_sets(pairs: list[str] | None) -> list[tuple[str, list[str], Any]]:
    """``["infer.tta=2"]`` → ``[("infer.tta=2", ["infer", "tta"], 2)]``: values are YAML
    (``true``, ``5``, ``[1, 2]``, ``{kind: dbscan}``; anything else stays a string).

    Raises:
        ConfigError: an entry without ``=`` or with an empty key part.
    """
    import yaml

    out = []
    for pair in pairs or []:
        key, sep, text = pair.partition("=")
        path = key.strip().split(".")
        if not sep or not all(path):
            raise ConfigError(f"--set {pair!r}: expected KEY=VALUE with a dotted key (e.g. infer.tta=2)")
        try:
            value = yaml.safe_load(text) if text.strip() else ""
        except yaml.YAMLError:
            value = text
        out.append((pair, path, value))
    return out


def default_config(method: str | None = None) -> LabelConfig:
    """The full default config of ``method`` (the default method when None): every stage's config
    with its defaults filled in (``dsnet config dump``). ``ingest.grid`` stays null: the run takes
    it from the model its stages name."""
    m = get_method(method)
    settings = m.Settings()
    options = _default_method_options(m, settings)
    stages = m.stage_settings(settings)
    pipeline = m.pipeline(options, stages)
    return LabelConfig(
        method=m.name, method_options=options, stages=filled_stages(pipeline, stages), options=RunOptions()
    )


def _default_method_options(method: Method, settings: LabelSettings) -> dict[str, Any]:
    """What the method's pipeline records by default, with each option a setting names at that
    setting's default (``temporal: auto``, not the association it resolves to)."""
    recorded = method.pipeline(method.options(settings), method.stage_settings(settings)).record()
    out = dict(recorded["method_options"])
    for key in out:
        default = getattr(settings, key, None)
        if default is not None:
            out[key] = default
    return out


def filled_stages(pipeline: Pipeline, stages: Mapping[str, Mapping[str, Any]]) -> dict[str, dict[str, Any]]:
    """Every stage of ``pipeline`` with its config validated and its defaults filled in (JSON)."""
    return {
        s.name: s.Config.model_validate(dict(stages.get(s.name, {}))).model_dump(mode="json")
        for s in pipeline.stages
    }


def resolve(
    file: Mapping[str, Any] | None = None,
    *,
    source: str = "--config",
    method: str | None = None,
    settings: Mapping[str, Any] | None = None,
    given: Mapping[str, Any] | None = None,
    sets: list[str] | None = None,
) -> LabelConfig:
    """The config of a run: the method's defaults, then ``file`` (a :func:`read_config` mapping,
    named ``source`` in errors), then the command line's ``method``, label ``settings`` given
    (:attr:`~tasks.methods.base.Method.Settings` fields) and the run's own keys ``given``
    (:class:`LabelConfig` keys: ``format``, ``sequences``, ``options``: {...}, ``reader_options``),
    then the ``--set`` overrides. Stage configs stay as overrides (defaults are filled in by the
    stages); :func:`filled_stages` fills them.

    Raises:
        ConfigError: one line naming the key and its layer (an unknown stage or key, a bad value).
        ValueError: a setting the method does not take (naming its flag), an unknown method.
    """
    file = dict(file or {})
    parsed = parse_sets(sets)
    top_sets = {p[0]: v for _, p, v in parsed if len(p) == 1}
    name = top_sets.get("method") or method or file.get("method") or DEFAULT_METHOD
    m = get_method(str(name))
    typed = m.settings_of(LabelSettings(**dict(settings or {})))
    defaults = m.Settings()
    out: dict[str, Any] = {
        "method": m.name,
        "method_options": m.options(defaults),
        "stages": m.stage_settings(defaults),
    }

    _lay(out, {k: v for k, v in file.items() if k != "method"})  # the file
    _check(out, m, lambda key: f"{source}: {key}", values=True)

    cli_options, cli_stages = m.options(typed), m.stage_settings(typed)  # the flags
    for flag_name in settings or {}:
        _take(out["method_options"], cli_options, flag_name)
        for dotted in m.stage_keys.get(flag_name, ()):
            stage, _, key = dotted.partition(".")
            _take(out["stages"].setdefault(stage, {}), cli_stages.get(stage, {}), key)
    _lay(out, dict(given or {}))
    _check(out, m, str, flags=True)

    for pair, path, value in parsed:  # the overrides
        if path == ["method"]:
            continue
        _assign(out, path, value, pair)
    _check(out, m, lambda key: _set_name(parsed, key))
    out["stages"] = {k: v for k, v in out["stages"].items() if v}
    return LabelConfig.model_validate(out)


def _take(target: dict[str, Any], source: Mapping[str, Any], key: str) -> None:
    """``target[key]`` as ``source`` has it; absent there: removed (the default again)."""
    if key in source:
        target[key] = copy.deepcopy(source[key])
    else:
        target.pop(key, None)


def _lay(out: dict[str, Any], layer: Mapping[str, Any]) -> None:
    """Merge ``layer`` (config keys) into ``out``: mappings key by key, the rest replaced."""
    for key, value in layer.items():
        if key == "stages":
            if not isinstance(value, dict):
                raise ConfigError(f"stages: expected a mapping of stage names, got {value!r}")
            for stage, config in value.items():
                if not isinstance(config, dict):
                    raise ConfigError(f"stages.{stage}: expected a mapping of its settings, got {config!r}")
                out["stages"].setdefault(stage, {}).update(copy.deepcopy(config))
        elif isinstance(value, dict) and key in ("method_options", "reader_options", "options"):
            out.setdefault(key, {})
            if not isinstance(out[key], dict):
                out[key] = dict(out[key])
            out[key].update(copy.deepcopy(value))
        else:
            out[key] = copy.deepcopy(value)


def _assign(out: dict[str, Any], path: list[str], value: Any, pair: str) -> None:
    """One ``--set``: a first key that is no :class:`LabelConfig` key names a stage."""
    if path[0] not in SECTIONS:
        path = ["stages", *path]
    if path[0] == "stages" and len(path) < 3:
        raise ConfigError(f"--set {pair}: expected STAGE.KEY=VALUE (e.g. infer.tta=2)")
    if path[0] in ("format", "sequences") and len(path) > 1:
        raise ConfigError(f"--set {pair}: {path[0]} takes no sub-key")
    node = out
    for i, part in enumerate(path[:-1]):
        child = node.get(part)
        if child is None:
            child = node[part] = {}
        elif not isinstance(child, dict):
            if isinstance(child, BaseModel):
                child = node[part] = child.model_dump()
            else:
                where = ".".join(path[1 : i + 1] if path[0] == "stages" else path[: i + 1])
                raise ConfigError(f"--set {pair}: {where} is {child!r}, not a mapping")
        node = child
    node[path[-1]] = value


def _check(out: dict[str, Any], method: Method, name, flags: bool = False, values: bool = False) -> None:
    """Check ``out`` as it stands: the config's own keys, the method's options and every stage's
    config; ``name(key)`` says where a dotted key came from (with ``flags``, a stage setting a flag
    wrote is named by its flag: :func:`~tasks.methods.stage_config_line`; with ``values``, a bad
    value is shown after its key).

    Raises:
        ConfigError: one line naming the first bad key.
    """
    top = {k: v for k, v in out.items() if k != "stages"}
    try:
        LabelConfig.model_validate(top)
    except ValidationError as exc:
        err = exc.errors()[0]
        key = ".".join(str(p) for p in err.get("loc", ()))
        raise ConfigError(f"{name(key)}{_message(err, values)}") from None
    try:
        pipeline, failed = method.pipeline(out["method_options"], out["stages"]), None
    except ValueError as exc:  # the stages first: a bad one may be why (align.scans: x)
        failed = ConfigError(f"{name('method_options')}: {exc}")
        try:
            pipeline = method.pipeline(out["method_options"])
        except ValueError:
            raise failed from None
    stages = pipeline.names()
    for stage, config in out["stages"].items():
        if stage not in stages:
            raise ConfigError(
                f"{name(stage)}: no stage {stage!r} in method {method.name} (stages: {', '.join(stages)})"
            )
        cls = pipeline[stage].Config
        unknown = [k for k in config if k not in cls.model_fields]
        if unknown:
            raise ConfigError(
                f"{name(stage + '.' + unknown[0])}: not a setting of stage {stage} "
                f"(its settings: {', '.join(cls.model_fields)})"
            )
        try:
            cls.model_validate(config)
        except ValidationError as exc:
            if flags:
                from tasks.methods import stage_config_line

                raise ConfigError(stage_config_line(stage, exc)) from None
            err = exc.errors()[0]
            key = ".".join([stage, *(str(p) for p in err.get("loc", ()))])
            raise ConfigError(f"{name(key)}{_message(err, values)}") from None
    if failed is not None:
        raise failed


def _message(err: Mapping[str, Any], value: bool) -> str:
    """A pydantic error as ``[ <value>]: <message>`` (the value only where it is a plain one)."""
    shown = err.get("input")
    plain = value and not (isinstance(shown, dict | list) or shown is None)
    ctx = err.get("ctx") or {}
    if err.get("type") == "union_tag_invalid":
        tag = f" {ctx.get('tag')!r}" if value else ""
        return f"{tag}: not a kind it takes (expected: {ctx.get('expected_tags')})"
    msg = str(err.get("msg", "invalid")).removeprefix("Value error, ")
    return f"{f' {shown!r}' if plain else ''}: {msg}"


def _set_name(parsed: list[tuple[str, list[str], Any]], key: str) -> str:
    """The ``--set`` entry that wrote ``key`` (a dotted key; stages without their section)."""
    for pair, path, _ in reversed(parsed):
        dotted = ".".join(path[1:] if path[0] == "stages" else path)
        if key == dotted or key.startswith(dotted + ".") or dotted.startswith(key + "."):
            return f"--set {pair}"
    return key


def resolved_config(
    request: LabelRequest, pipeline: Pipeline, log_format: str, sequences: list[str]
) -> LabelConfig:
    """What a run was configured with, every default filled in (its folder's ``config.yaml``): the
    method and the options its pipeline recorded, the log's detected ``log_format``, the
    ``sequences`` it labels, every stage's config (ingest's grid from the model included) and the run
    options. ``dsnet label LOG --run R2 --config R/config.yaml`` labels alike."""
    return LabelConfig(
        method=pipeline.name,
        method_options=dict(pipeline.options),
        format=log_format,
        reader_options=dict(request.reader_options),
        sequences=list(sequences),
        stages=filled_stages(pipeline, request.stage_configs(pipeline)),
        options=request.options,
    )
