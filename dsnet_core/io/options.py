"""Reader options: what each format's reader accepts, checked before the reader opens.

A format declares its options as :class:`ReaderOption` values (:mod:`dsnet_core.io.formats`): a
name, the values it allows in words, and a parser that turns a value from the command line
(``--reader-option KEY=VALUE``, already a YAML scalar: ``5``, ``true``, ``0.1`` or text) or from a
run config into what the reader takes, or raises :class:`ValueError` saying why not. A value that
does not parse is one :class:`~dsnet_core.errors.ConfigError` line naming the log, the option, the
value and what is allowed (:func:`check_options`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from dsnet_core.errors import ConfigError
from dsnet_core.labels import LabelMap, builtin_label_maps, load_label_map


@dataclass(frozen=True)
class ReaderOption:
    """One reader option.

    Attributes:
        name: the keyword the reader's constructor takes (``bin_columns``).
        allowed: what the option takes, in words, for the error message (``4 or 5``).
        parse: value -> what the reader takes; raises ValueError naming what is wrong.
    """

    name: str
    allowed: str = "any value"
    parse: Callable[[Any], Any] = lambda value: value


def check_options(
    root: str | Path, fmt: str, declared: Iterable[ReaderOption], options: Mapping | None
) -> dict:
    """Parse ``options`` against the options a format declares.

    Options given as None are left out (the reader's default applies).

    Returns:
        The parsed options, by name.

    Raises:
        ConfigError: an option the format does not declare (listing those it does), or a value
            its parser refuses (naming the option, the value and what is allowed).
    """
    specs = {spec.name: spec for spec in declared}
    unknown = sorted(set(options or {}) - set(specs))
    if unknown:
        raise ConfigError(
            f"{root}: the {fmt} reader has no option {', '.join(map(repr, unknown))}; its options are "
            f"{', '.join(specs) or 'none'}"
        )
    out = {}
    for name, value in (options or {}).items():
        if value is None:
            continue
        spec = specs[name]
        try:
            out[name] = spec.parse(value)
        except ValueError as exc:
            reason = " ".join(str(exc).split())
            raise ConfigError(
                f"{root}: reader option {name}={_show(value)} is not allowed"
                f"{f' ({reason})' if reason else ''}; the {fmt} reader takes {spec.allowed}"
            ) from exc
    return out


def _show(value: Any) -> str:
    return repr(value) if isinstance(value, str) else str(value)


# -- parsers ------------------------------------------------------------------------------------
def text(value: Any) -> str:
    """A non-empty text (a number the command line read as YAML becomes its text)."""
    if isinstance(value, bool) or not isinstance(value, str | int | float):
        raise ValueError(f"a {type(value).__name__}, not a text")
    out = str(value).strip()
    if not out:
        raise ValueError("empty")
    return out


def boolean(value: Any) -> bool:
    """true/false (YAML booleans; the texts true/false/yes/no/on/off; 1/0)."""
    if isinstance(value, bool):
        return value
    if isinstance(value, int) and value in (0, 1):
        return bool(value)
    if isinstance(value, str) and value.strip().lower() in _WORDS:
        return _WORDS[value.strip().lower()]
    raise ValueError("")


_WORDS = {"true": True, "yes": True, "on": True, "false": False, "no": False, "off": False}


def seconds(value: Any) -> float:
    """A finite number of seconds, ≥ 0."""
    if isinstance(value, bool):
        raise ValueError("")
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise ValueError("") from None
    if not math.isfinite(out) or out < 0:
        raise ValueError("")
    return out


def choice(*values: str) -> Callable[[Any], str]:
    """One of ``values`` (texts, compared as given)."""

    def parse(value: Any) -> str:
        if not isinstance(value, str) or value not in values:
            raise ValueError("")
        return value

    return parse


def int_choice(*values: int) -> Callable[[Any], int]:
    """One of the integers ``values`` (or its text)."""

    def parse(value: Any) -> int:
        if isinstance(value, str) and value.strip().isdigit():
            value = int(value)
        if isinstance(value, bool) or not isinstance(value, int) or value not in values:
            raise ValueError("")
        return value

    return parse


def suffix(known: Iterable[str]) -> Callable[[Any], str]:
    """One of the scan suffixes ``known`` (``.pcd``), with or without its dot, any case."""
    known = tuple(known)

    def parse(value: Any) -> str:
        if not isinstance(value, str):
            raise ValueError("")
        key = value.strip().lower()
        key = key if key.startswith(".") else f".{key}"
        if key not in known:
            raise ValueError("")
        return key

    return parse


def label_map(only: str | None = None) -> Callable[[Any], LabelMap]:
    """A :class:`LabelMap`, the name of a bundled one or a label-map YAML file; with ``only``, that
    bundled map alone (a format whose ground truth has one class set)."""

    def parse(value: Any) -> LabelMap:
        if isinstance(value, LabelMap):
            lm = value
        elif isinstance(value, Path) or (
            not isinstance(value, bool) and isinstance(value, str | int | float)
        ):
            name = str(value).strip()  # a number the command line read as YAML is a file name
            if name not in builtin_label_maps() and not Path(name).expanduser().is_file():
                raise ValueError(f"no bundled label map or YAML file {name!r}")
            try:
                lm = load_label_map(name if name in builtin_label_maps() else Path(name).expanduser())
            except ConfigError as exc:
                raise ValueError(str(exc)) from exc
        else:
            raise ValueError(f"a {type(value).__name__}, not a name or a path")
        if only is not None and lm.name != only:
            raise ValueError(f"the {lm.name} label map")
        return lm

    return parse


def label_map_allowed(only: str | None = None) -> str:
    """The words for :func:`label_map`'s ``allowed``."""
    if only is not None:
        return f"label_map={only} only (its ground truth's classes)"
    return f"a bundled label map ({', '.join(builtin_label_maps())}) or the path of a label-map YAML file"


def as_label_map(value: LabelMap | str | Path | None, default: str) -> LabelMap:
    """A reader's ``label_map`` argument as a :class:`LabelMap` (None: the bundled ``default``).

    Raises:
        ConfigError: an unknown name or an unreadable YAML file.
    """
    if isinstance(value, LabelMap):
        return value
    return load_label_map(default if value is None else value)
