"""Deliberately altered sensor physics (``dsnet synth --physics KEY=VALUE``): a LiDAR no preset and no
random draw produces, for domain-shift benchmarks (``bench/bench_adapt.py``).

Keys (values as text; :func:`parse_physics`):

- ``elevations``: the beam pattern, ``uniform:B:TOP:BOTTOM`` (B beams evenly from TOP° to BOTTOM°)
  or a comma-separated list of degrees, top beam first (the beams' gains become 1);
- ``azimuth_steps``: firings per revolution and beam;
- ``height``: mounting height above the road (metres);
- ``remission_gain``, ``falloff``: the remission model's global gain and range fall-off (metres);
- ``dropout``, ``far_dropout``: ray drop, anywhere and growing with range² for dark targets;
- ``range_noise``, ``min_range``, ``max_range``: metres.

The override applies after the sequence's own draws; ``synth.json`` records it under ``physics``.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from dsnet_core.errors import ConfigError
from dsnet_core.synth.sensor import LidarSpec

FLOATS = (
    "height",
    "remission_gain",
    "falloff",
    "dropout",
    "far_dropout",
    "range_noise",
    "min_range",
    "max_range",
)
KEYS = ("elevations", "azimuth_steps", *FLOATS)


def elevations(text: str) -> tuple[float, ...]:
    """``uniform:B:TOP:BOTTOM`` or ``a,b,c`` (degrees) → beam elevations, top beam first.

    Raises:
        ConfigError: anything else, fewer than 2 beams, or angles outside ±90°.
    """
    try:
        if text.startswith("uniform:"):
            _, beams, top, bottom = text.split(":")
            values = np.linspace(float(top), float(bottom), int(beams)).tolist()
        else:
            values = [float(v) for v in text.split(",")]
    except ValueError:
        raise ConfigError(
            f"--physics elevations={text!r}: expected uniform:B:TOP:BOTTOM or a list of degrees"
        ) from None
    if len(values) < 2 or any(abs(v) >= 90 for v in values):
        raise ConfigError(f"--physics elevations={text!r}: need at least 2 beams within ±90°")
    return tuple(sorted((float(v) for v in values), reverse=True))


def parse_physics(pairs: list[str] | None) -> dict[str, Any]:
    """``["height=2.3", "elevations=uniform:40:8:-22"]`` →
    ``{"height": 2.3, "elevations": "uniform:40:8:-22"}``, each value checked.

    Raises:
        ConfigError: an entry without ``=``, an unknown key (the message lists them), a bad value.
    """
    out: dict[str, Any] = {}
    for pair in pairs or []:
        key, sep, value = pair.partition("=")
        key = key.strip().replace("-", "_")
        if not sep or key not in KEYS:
            raise ConfigError(f"--physics {pair!r}: expected KEY=VALUE with KEY one of {', '.join(KEYS)}")
        try:
            out[key] = (
                value if key == "elevations" else int(value) if key == "azimuth_steps" else float(value)
            )
        except ValueError:
            raise ConfigError(f"--physics {pair!r}: {key} wants a number") from None
        positive = key in ("azimuth_steps", "height", "falloff", "max_range")
        if key == "elevations":
            elevations(value)
        elif out[key] <= 0 if positive else out[key] < 0:
            raise ConfigError(f"--physics {pair!r}: {key} must be {'> 0' if positive else '≥ 0'}")
        elif key in ("dropout", "far_dropout") and out[key] >= 1:
            raise ConfigError(f"--physics {pair!r}: a drop probability must be below 1")
    return out


def apply_physics(spec: LidarSpec, physics: dict[str, Any] | None) -> LidarSpec:
    """``spec`` with the :func:`parse_physics` overrides (unchanged without any)."""
    if not physics:
        return spec
    values: dict[str, Any] = {k: v for k, v in physics.items() if k in FLOATS or k == "azimuth_steps"}
    if "elevations" in physics:
        values["elevations_deg"] = elevations(str(physics["elevations"]))
        values["beam_gains"] = ()
    return replace(spec, **values)
