"""A street's cross-section: carriageway (lanes, median, bike lane), kerbside strip, verge, sidewalk."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dsnet_core.synth.road import ROAD, TERRAIN


@dataclass(frozen=True)
class Section:
    """A street's cross-section, per side (0 left, 1 right), widths in metres.

    Attributes:
        lanes: traffic lanes per side.
        lane_width: metres.
        median: full width of a raised central median (0: none).
        median_class: raw class of the median (terrain: grass, sidewalk: paved island).
        bike: bike-lane width per side behind a solid line (0: none).
        widths: ``(2, 3)`` kerbside strip, verge (grass), sidewalk widths per side.
        road_class: raw class of the carriageway (road; parking in a parking lot).
        markings: paint lane markings.
        flush_kerbside: the kerbside strip is level with the road whatever its class (gravel).
    """

    lanes: int
    lane_width: float
    median: float = 0.0
    median_class: int = TERRAIN
    bike: float = 0.0
    widths: tuple[tuple[float, float, float], tuple[float, float, float]] = ((0, 0, 2.0), (0, 0, 2.0))
    road_class: int = ROAD
    markings: bool = True
    flush_kerbside: bool = False

    @property
    def carriageway(self) -> float:
        """|d| of the kerb line (metres)."""
        return self.median / 2 + self.lanes * self.lane_width + self.bike

    def edges(self, side: int) -> np.ndarray:
        """``(4,)`` |d| of road edge, kerbside end, verge end, sidewalk end."""
        return np.cumsum([self.carriageway, *self.widths[side]])

    def lane_centres(self) -> list[float]:
        """|d| of the centre of each lane, inner first."""
        return [self.median / 2 + (m - 0.5) * self.lane_width for m in range(1, self.lanes + 1)]
