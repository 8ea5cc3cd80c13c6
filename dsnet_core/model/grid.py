"""The cylindrical grid's geometry (:class:`CylinderGrid`), without torch: model cards, presets
and the command line read it; :mod:`dsnet_core.model.cylinder` voxelises with it."""

from __future__ import annotations

import math
from dataclasses import dataclass

CONVENTIONS = ("ours", "reference")
MAX_CELLS = 1 << 31
"""The largest grid taken (ρ·φ·z cells, ~2.1e9: 390× the paper's 480×360×32). Voxel keys are
``batch · cells`` int64 and each sparse level's dense lookup table (int32, up to 2^26 cells:
256 MB) is sized from the cell count; no trained model comes near, and a card asking for more
(a 1e12-cell grid labels "fine" with every point in a cell of its own) is refused."""


@dataclass(frozen=True)
class CylinderGrid:
    """A cylindrical grid.

    Attributes:
        size: cells along (ρ, φ, z).
        min_bound: lower bounds (ρ metres, φ radians, z metres).
        max_bound: upper bounds; points outside are clamped into the edge cells.
        convention: ``"ours"`` (cell = (max − min) / n) or ``"reference"`` ((max − min) / (n − 1)).
    """

    size: tuple[int, int, int] = (480, 360, 32)
    min_bound: tuple[float, float, float] = (3.0, -math.pi, -3.0)
    max_bound: tuple[float, float, float] = (50.0, math.pi, 1.5)
    convention: str = "ours"

    def __post_init__(self) -> None:
        if len(self.size) != 3 or min(self.size) < 1:
            raise ValueError(f"grid size must be three positive ints, got {self.size}")
        cells = math.prod(self.size)
        if cells > MAX_CELLS:
            raise ValueError(
                f"grid {'×'.join(map(str, self.size))} has {cells:.3g} cells, more than the {MAX_CELLS:.3g} "
                "(2^31) a grid may have (the paper's 480×360×32 has 5.5e+06)"
            )
        if any(hi <= lo for lo, hi in zip(self.min_bound, self.max_bound, strict=True)):
            raise ValueError(f"grid bounds must satisfy min < max, got {self.min_bound}..{self.max_bound}")
        if self.convention not in CONVENTIONS:
            raise ValueError(
                f"unknown grid convention {self.convention!r} (choose from {', '.join(CONVENTIONS)})"
            )
        if self.convention == "reference" and min(self.size) < 2:
            raise ValueError(f"the reference convention needs at least 2 cells per axis, got {self.size}")

    @property
    def interval(self) -> tuple[float, float, float]:
        """Cell size along (ρ, φ, z) in metres / radians: (max − min) / n, or / (n − 1) for the
        reference convention."""
        cut = 1 if self.convention == "reference" else 0
        bounds = zip(self.min_bound, self.max_bound, self.size, strict=True)
        return tuple((hi - lo) / (n - cut) for lo, hi, n in bounds)

    def to_dict(self) -> dict:
        """Plain dict; ``convention`` appears only when not the default (older cards stay equal)."""
        d = {"size": list(self.size), "min_bound": list(self.min_bound), "max_bound": list(self.max_bound)}
        if self.convention != "ours":
            d["convention"] = self.convention
        return d

    @classmethod
    def from_dict(cls, d: dict) -> CylinderGrid:
        return cls(
            tuple(int(v) for v in d["size"]),
            tuple(d["min_bound"]),
            tuple(d["max_bound"]),
            str(d.get("convention", "ours")),
        )
