"""Stuff several styles build: garden boundaries (hedges, fences, walls) and houses."""

from __future__ import annotations

from dsnet_core.synth.layout import BUILDING, FENCE, VEGETATION
from dsnet_core.synth.primitives import BOX, Part
from dsnet_core.synth.styles.base import StylePlacer


def boundary(placer: StylePlacer, s0: float, s1: float, d: float) -> None:
    """A hedge, a fence or a garden wall of varied height along ``[s0, s1]`` (or nothing)."""
    rng = placer.rng
    kind = rng.choice(4, p=[0.4, 0.25, 0.15, 0.2])
    if kind == 0:
        placer.along(
            s0, s1, d, rng.uniform(0.5, 1.2), rng.uniform(0.6, 2.4), VEGETATION, rng.uniform(0.3, 0.55)
        )
    elif kind == 1:
        placer.along(s0, s1, d, 0.05, rng.uniform(0.6, 2.0), FENCE, rng.uniform(0.2, 0.5))
    elif kind == 2:
        placer.along(s0, s1, d, rng.uniform(0.2, 0.35), rng.uniform(0.4, 1.8), FENCE, rng.uniform(0.2, 0.45))


def house(placer: StylePlacer, sc: float, d: float, length: float, depth: float, sign: float) -> None:
    """A house: walls and a ridged roof (two stacked, narrower boxes)."""
    rng = placer.rng
    h = rng.uniform(3.0, 7.0)
    refl = rng.uniform(0.15, 0.55)
    parts = [Part(BOX, (0.0, 0.0, h / 2), (length / 2, depth / 2, h / 2), refl)]
    if rng.random() < 0.7:
        roof = rng.uniform(0.15, 0.55)
        parts += [
            Part(
                BOX, (0.0, 0.0, h + 0.6), (length / 2, depth * (0.5 - roof / 2), 0.6), rng.uniform(0.1, 0.4)
            ),
            Part(BOX, (0.0, 0.0, h + 1.6), (length / 2, depth * (0.5 - roof), 0.4), rng.uniform(0.1, 0.4)),
        ]
    placer.place(parts, sc, d, BUILDING)
