"""Intensity conventions: what a log's intensity column means, and the one function that turns
it into the model's 0–1 remission.

Every reader states its source convention (attribute ``intensity`` of the reader) and returns
scans in the model's convention, through :func:`normalise_intensity` only:

========  ==========================================  ===============================
name      source values                               model remission
========  ==========================================  ===============================
unit      float in [0, 1] (SemanticKITTI remission)   unchanged (float32)
uint8     0–255, integer or float (nuScenes, Velodyne)  ``float32(v) / 255``
uint16    0–65535 (LAS, Ouster reflectivity)          ``float32(v) / 65535``
none      no intensity channel                        0 for every point
========  ==========================================  ===============================

Values outside the convention's range are an error (a wrong convention would silently feed the
model a different sensor), never clipped. :func:`infer_convention` is the stated rule for a column
whose convention the format does not fix: ``uint8``/``uint16`` columns are what their type says;
a float column is ``unit`` when its maximum is at most 1, ``uint8`` when at most 255, ``uint16``
when at most 65535. Readers apply it once per sequence (on its first scan) so that every frame of
a sequence is scaled alike; a reader option overrides it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dsnet_core.errors import IntensityFormatError

MODEL_CONVENTION = "unit"
FULL_SCALE: dict[str, float | None] = {"unit": 1.0, "uint8": 255.0, "uint16": 65535.0, "none": None}
CONVENTIONS = tuple(FULL_SCALE)
_FLOATS = (np.float32, np.float64, np.float16)


def check_column(values: np.ndarray, path: str | Path, field: str = "intensity") -> None:
    """Raise when an intensity column's type cannot hold a supported convention.

    Accepted: uint8, uint16 and floating-point columns.

    Raises:
        IntensityFormatError: any other type (signed or 32/64-bit integers, strings, lists).
    """
    dt = np.asarray(values).dtype
    if dt in (np.uint8, np.uint16) or dt.type in _FLOATS:
        return
    raise IntensityFormatError(
        path, f"{field} column has type {dt}; expected uint8, uint16 or a float (conventions {CONVENTIONS})"
    )


def infer_convention(values: np.ndarray | None, path: str | Path, field: str = "intensity") -> str:
    """The convention of an intensity column, by the rule in the module docstring.

    Args:
        values: the column, ``(N,)``, or None when the source has no intensity.

    Raises:
        IntensityFormatError: an unsupported type, non-finite values, or floats above 65535.
    """
    if values is None:
        return "none"
    check_column(values, path, field)
    values = np.asarray(values)
    if values.dtype == np.uint8:
        return "uint8"
    if values.dtype == np.uint16:
        return "uint16"
    if values.size == 0:
        return "unit"
    if not np.isfinite(values).all():
        raise IntensityFormatError(path, f"{field} column holds NaN or inf values")
    top = float(values.max())
    for name in ("unit", "uint8", "uint16"):
        if top <= FULL_SCALE[name]:  # type: ignore[operator]
            return name
    raise IntensityFormatError(path, f"{field} values reach {top:g}, above every convention's range (65535)")


def normalise_intensity(
    values: np.ndarray | None, convention: str, path: str | Path, n_points: int | None = None
) -> np.ndarray:
    """Source intensity -> the model's remission, float32 ``(N,)`` in [0, 1].

    Args:
        values: the source column ``(N,)`` (any accepted type), or None for ``none``.
        convention: one of :data:`CONVENTIONS`.
        path: the file, for error messages.
        n_points: N, needed when ``values`` is None.

    Raises:
        IntensityFormatError: unknown convention, unsupported type, non-finite values, or
            values outside the convention's range.
    """
    if convention not in FULL_SCALE:
        raise IntensityFormatError(path, f"unknown intensity convention {convention!r}; known: {CONVENTIONS}")
    scale = FULL_SCALE[convention]
    if scale is None or values is None:
        if values is None and n_points is None:
            raise ValueError("n_points is needed when there is no intensity column")
        return np.zeros(n_points if values is None else len(values), dtype=np.float32)
    check_column(values, path)
    v = np.array(values, dtype=np.float32)  # always a copy: the caller's column is never scaled
    if v.size:
        lo, hi = float(v.min()), float(v.max())
        if not (np.isfinite(lo) and np.isfinite(hi)):
            raise IntensityFormatError(path, "intensity column holds NaN or inf values")
        if lo < 0 or hi > scale:
            raise IntensityFormatError(
                path,
                f"intensity values span [{lo:g}, {hi:g}], outside the {convention} convention's "
                f"[0, {scale:g}]; state the right convention (one of {CONVENTIONS})",
            )
    if convention == "unit":
        return v
    v /= np.float32(scale)
    return v


def quantise(remission: np.ndarray, convention: str) -> np.ndarray:
    """Round 0–1 remission to a convention's quantum and return it in source units (float64).

    ``normalise_intensity(quantise(r, c).astype(dtype), c, ...)`` equals
    ``normalise_intensity(quantise(r, c), c, ...)`` bit for bit: used to build exact fixtures.
    """
    scale = FULL_SCALE[convention]
    if scale is None:
        return np.zeros(len(remission))
    r = np.asarray(remission, dtype=np.float64)
    return r if convention == "unit" else np.round(np.clip(r, 0, 1) * scale)
