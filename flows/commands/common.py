"""What every command shares: one way to turn a typed error into ``error: ...`` and exit code 2."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from typing import NoReturn

import typer

FORMAT_HELP = (
    "Log format: auto (detect), semantickitti, nuscenes, folder or rosbag; the same names as "
    "`dsnet export --format`."
)
TOPIC_HELP = "ROS 2 bags: the PointCloud2 topic (needed when a bag has several; reader option topic)."
FIXED_FRAME_HELP = (
    "ROS 2 bags: the tf frame poses are taken in (default map, else odom; reader option fixed_frame)."
)
READER_OPTION_HELP = (
    "A reader option KEY=VALUE, repeatable (nuscenes: sweeps=true, version=v1.0-mini; rosbag: "
    "topic=/points, fixed_frame=odom, intensity=uint16; folder: order=time, intensity=uint8, "
    "bin_columns=5, suffix=pcd). Recorded in the run."
)


def fail(exc: BaseException | str, code: int = 2) -> NoReturn:
    """Print ``error: <message>`` in red on stderr and exit with ``code`` (2: bad input or settings)."""
    typer.secho(f"error: {exc}", fg=typer.colors.RED, err=True)
    raise typer.Exit(code=code)


@contextlib.contextmanager
def errors_exit() -> Iterator[None]:
    """Turn the project's typed errors (bad input, store problems, invalid settings) into :func:`fail`.

    Only typed errors: anything else is a bug and keeps its traceback.
    """
    from pydantic import ValidationError

    from dsnet_core.errors import DsnetError
    from storage.errors import StoreError, as_write_error

    try:
        yield
    except ValidationError as exc:
        fail(validation_line(exc))
    except (DsnetError, StoreError, ValueError) as exc:
        fail(exc)
    except OSError as exc:  # a full or read-only disk met outside the store's own writes
        typed = as_write_error(exc, "the output")
        if typed is None:
            raise
        fail(typed)


def check_output(path, option: str, kind: str) -> None:
    """Refuse an output path before anything is written: ``kind`` ``"folder"`` must not be a file (nor
    lie under one), ``"file"`` must not be a folder (nor lie under a file).

    Raises:
        OutputPathError: naming the path, the option and what to give instead.
    """
    from pathlib import Path

    from dsnet_core.errors import OutputPathError

    here = Path(path).expanduser().absolute()
    for above in reversed(here.parents):
        if above.exists() and not above.is_dir():
            raise OutputPathError(above, f"is a file, so {option} {path} cannot be written under it")
    if kind == "folder" and here.exists() and not here.is_dir():
        raise OutputPathError(here, f"is a file, but {option} names the folder to write: give a folder")
    if kind == "file" and here.is_dir():
        raise OutputPathError(here, f"is a folder, but {option} names the file to write: give a file name")


def validation_line(exc) -> str:
    """A pydantic ValidationError of command-line settings as one line naming each option:
    ``--scans 0: Input should be greater than or equal to 1``."""
    parts = []
    for err in exc.errors():
        loc = [str(p) for p in err.get("loc", ())]
        name = "--" + loc[0].replace("_", "-") if len(loc) == 1 else ".".join(loc) or "value"
        shown = err.get("input")
        value = "" if isinstance(shown, dict) or shown is None else f" {shown!r}"
        msg = str(err.get("msg", "invalid")).removeprefix("Value error, ")
        parts.append(msg if msg.startswith(name + " ") else f"{name}{value}: {msg}")
    return "; ".join(parts)
