"""The labelling methods, one object per module (:class:`~tasks.methods.base.Method`), and their
registry. Adding a method is one module and one line in :data:`METHODS` (or :func:`register` for
a method defined elsewhere, e.g. in a test or a plugin).

``dsnet`` is DS-Net (k = 1) and 4D-DS-Net (k > 1): ingest → align → infer → shift → fuse →
stitch (or track) → score. ``most`` is MOST: ingest → align (single scans) → most → track → score.
``dpls`` is D-PLS: ingest → align → prior → dpls → shift → fuse → stitch (or track) → score.
Stages shared with another method (ingest, align) keep their names, so switching methods
recomputes only what differs.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from tasks.methods.base import LabelSettings, Method, TrainOptions
from tasks.methods.dpls import DPLS
from tasks.methods.dsnet import DSNET
from tasks.methods.most import MOST

if TYPE_CHECKING:
    from tasks.pipeline import Pipeline

METHODS: dict[str, Method] = {m.name: m for m in (DSNET, MOST, DPLS)}
"""Every method by name, in the order help texts list them."""
DEFAULT_METHOD = DSNET.name

__all__ = [
    "DEFAULT_METHOD",
    "METHODS",
    "LabelSettings",
    "Method",
    "TrainOptions",
    "get_method",
    "register",
    "stage_config_line",
]


def get_method(name: str | None = None) -> Method:
    """The method called ``name`` (the default method when None).

    Raises:
        ValueError: an unknown name (the message lists the methods).
    """
    name = name or DEFAULT_METHOD
    if name not in METHODS:
        raise ValueError(f"unknown method {name!r}; methods are {', '.join(METHODS)}")
    return METHODS[name]


def register(method: Method) -> Method:
    """Add ``method`` to the registry (a method defined outside this package); returns it.

    Raises:
        ValueError: another method already has its name.
    """
    if METHODS.get(method.name, method) is not method:
        raise ValueError(f"a method named {method.name!r} is already registered")
    METHODS[method.name] = method
    return method


def get_pipeline(method: str | None = None, **options: Any) -> Pipeline:
    """The pipeline of ``method`` built with ``options`` (its recorded ``method_options``)."""
    return get_method(method).pipeline(options)


def stage_configs(method: str | None = None, **settings: Any) -> dict[str, dict[str, Any]]:
    """The stage configs ``method`` makes of command-line ``settings`` (:class:`LabelSettings`
    fields): ``stage_configs("most", scans=4, checkpoint="/m")``.

    Raises:
        ValueError, pydantic.ValidationError: an unknown method, a setting it does not take, a bad value.
    """
    return get_method(method).stage_settings(LabelSettings(**settings))


def stage_config_line(stage: str, exc) -> str:
    """A stage config's pydantic ValidationError as one line naming the command-line option of each
    setting (``--clusterer 'bogus': not a kind (expected: 'dynamic_shift', ...)``); a setting no
    option gives is named ``stage.setting``."""
    from tasks.methods.base import flag

    settings = {name for m in METHODS.values() for name in m.Settings.model_fields}
    parts = []
    for err in exc.errors():
        loc = [str(p) for p in err.get("loc", ())]
        head = loc[0] if loc else ""
        name = flag(head) if head in settings else f"stage {stage} setting {head or '?'}"
        ctx = err.get("ctx") or {}
        if err.get("type") == "union_tag_invalid":
            parts.append(
                f"{name} {ctx.get('tag')!r}: not a kind it takes (expected: {ctx.get('expected_tags')})"
            )
        elif err.get("type") == "union_tag_not_found":
            parts.append(f"{name}: a JSON config needs a {ctx.get('discriminator', 'kind')} field")
        else:
            inner = ".".join(loc[1:])
            shown = err.get("input")
            value = "" if isinstance(shown, dict | list) or shown is None else f" {shown!r}"
            parts.append(f"{name}{': ' + inner if inner else ''}{value}: {err.get('msg', 'invalid')}")
    return "; ".join(parts)
