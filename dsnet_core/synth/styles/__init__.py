"""Street styles: a registry of scene builders chosen by name.

``classic`` is the original curved street (:func:`dsnet_core.synth.scene.build_scene`, output pinned);
the others paint a raster ground and draw from richer templates (:mod:`.base`).
"""

from __future__ import annotations

import numpy as np

from dsnet_core.errors import ConfigError
from dsnet_core.synth.config import SynthConfig
from dsnet_core.synth.scene import Scene, build_scene
from dsnet_core.synth.styles.base import StreetStyle
from dsnet_core.synth.styles.country import Country
from dsnet_core.synth.styles.places import Junction, ParkingLot
from dsnet_core.synth.styles.residential import Residential
from dsnet_core.synth.styles.urban import Arterial, Downtown

STYLES: dict[str, type[StreetStyle] | None] = {
    "classic": None,
    "residential": Residential,
    "arterial": Arterial,
    "downtown": Downtown,
    "junction": Junction,
    "parking_lot": ParkingLot,
    "country": Country,
}


def check_style(name: str, allow_random: bool = True) -> str:
    """``name`` if it is a style (or ``random``).

    Raises:
        ConfigError: unknown name.
    """
    if name in STYLES or (allow_random and name == "random"):
        return name
    raise ConfigError(f"unknown street style {name!r}; known: {sorted(STYLES)} or 'random'")


def build_styled_scene(style: str, rng: np.random.Generator, duration: float, config: SynthConfig) -> Scene:
    """The world of a sequence of ``style`` around an ego drive of ``duration`` seconds."""
    builder = STYLES[check_style(style, allow_random=False)]
    if builder is None:
        return build_scene(rng, duration, config)
    return builder().build(rng, duration, config)


__all__ = ["STYLES", "StreetStyle", "build_styled_scene", "check_style"]
