"""Ground surface detail of the ``wide`` variety, applied when a sweep is rendered: rough grass
(returns from blade tops at random heights) over an undulating terrain, and patchy remission of the
paved and grassy ground (repairs, stains, wet and dry, mown and long grass).

Real terrain is rough and at varied heights; a smooth, level lawn is a cue only a generator gives
(issue #32). Both effects act on the ground hits only, so primitives are untouched; a scene without
:class:`Surface` renders exactly as before.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import map_coordinates

from dsnet_core.synth.road import LANE_MARKING, OTHER_GROUND, PARKING, ROAD, SIDEWALK, TERRAIN

PATCHED = (ROAD, PARKING, SIDEWALK, OTHER_GROUND, TERRAIN, LANE_MARKING)
MAX_SHIFT = 2.5  # metres a ray's ground hit may move along the ray (grazing rays over long grass)
MIN_DESCENT = 0.03  # |dz| floor of the shift's 1/|dz| (rays nearly parallel to the ground)


@dataclass(frozen=True)
class Lattice:
    """Value noise: ``values (ny, nx)`` in [-1, 1] at ``origin + spacing · (j, i)``, bilinear between."""

    origin: tuple[float, float]
    spacing: float
    values: np.ndarray

    @staticmethod
    def draw(rng: np.random.Generator, lo: np.ndarray, hi: np.ndarray, spacing: float) -> Lattice:
        """Uniform values on a lattice covering the world box ``[lo, hi]`` (``(2,)`` metres)."""
        nx, ny = (np.ceil((np.asarray(hi) - lo) / spacing).astype(int) + 2).tolist()
        return Lattice((float(lo[0]), float(lo[1])), float(spacing), rng.uniform(-1.0, 1.0, (ny, nx)))

    def __call__(self, x: np.ndarray, y: np.ndarray, shift: float = 0.0) -> np.ndarray:
        """Noise at world ``(x, y)`` (metres), the lattice read ``shift`` cells off (another field)."""
        fi = (np.asarray(y) - self.origin[1]) / self.spacing + shift
        fj = (np.asarray(x) - self.origin[0]) / self.spacing + shift * 0.61803
        return map_coordinates(self.values, [fi, fj], order=1, mode="wrap")


@dataclass(frozen=True)
class Surface:
    """A styled street's ground detail.

    Attributes:
        grass: tallest grass (metres): a terrain return comes from ``grass · u²`` above the ground,
            ``u`` uniform per ray and sweep.
        undulation: terrain height amplitude (metres; lows below the raised level, highs above).
        relief: the undulation's lattice.
        patches: remission patch lattice.
        patchiness: ``(256,)`` per raw ground class, the remission's log-gain amplitude (0: uniform).
    """

    grass: float
    undulation: float
    relief: Lattice
    patches: Lattice
    patchiness: np.ndarray

    @staticmethod
    def draw(rng: np.random.Generator, lo: np.ndarray, hi: np.ndarray) -> Surface:
        """A street's detail over the world box ``[lo, hi]``, drawn from ``rng``."""
        patchiness = np.zeros(256)
        for c in PATCHED:
            patchiness[c] = rng.uniform(0.0, 0.45)
        return Surface(
            grass=float(rng.uniform(0.0, 0.3)),
            undulation=float(rng.uniform(0.0, 0.2)),
            relief=Lattice.draw(rng, lo, hi, float(rng.uniform(2.0, 8.0))),
            patches=Lattice.draw(rng, lo, hi, float(rng.uniform(1.0, 6.0))),
            patchiness=patchiness,
        )

    def roughen(
        self,
        origin: np.ndarray,
        world_dirs: np.ndarray,
        hits: tuple[np.ndarray, np.ndarray, np.ndarray],
        rng: np.random.Generator,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Ground hits ``(t, class, cos)`` with terrain hits moved to the grass and relief surface.

        Args:
            origin: ``(3,)`` sensor position (metres).
            world_dirs: ``(R, 3)`` unit ray directions in the world frame.
            hits: per ray the ground distance (inf: none), raw class and |cos incidence|.
            rng: draws the blade heights.
        """
        t, cls, cos = hits
        grass = np.flatnonzero((cls == TERRAIN) & np.isfinite(t))
        if not len(grass):
            return hits
        p = origin[None, :2] + t[grass, None] * world_dirs[grass, :2]
        height = self.undulation * self.relief(p[:, 0], p[:, 1])
        height += self.grass * rng.random(len(grass)) ** 2
        descent = np.maximum(-world_dirs[grass, 2], MIN_DESCENT)
        shift = np.clip(height / descent, -MAX_SHIFT, np.minimum(MAX_SHIFT, 0.5 * t[grass]))
        t = t.copy()
        t[grass] -= shift
        return t, cls, cos

    def patch(
        self, origin: np.ndarray, world_dirs: np.ndarray, t: np.ndarray, sem: np.ndarray, refl: np.ndarray
    ) -> np.ndarray:
        """Reflectivity of ground hits scaled by the patch field of their class (others unchanged).

        Args:
            t: ``(R,)`` hit distances (inf: none); sem: ``(R,)`` raw class; refl: ``(R,)`` reflectivity.
        """
        amp = self.patchiness[np.clip(sem, 0, 255)]
        on = np.flatnonzero((amp > 0) & np.isfinite(t))
        if not len(on):
            return refl
        p = origin[None, :2] + t[on, None] * world_dirs[on, :2]
        field = np.zeros(len(on))
        for c in np.unique(sem[on]):
            k = sem[on] == c
            field[k] = self.patches(p[k, 0], p[k, 1], shift=0.37 * float(c))
        refl = refl.copy()
        refl[on] = np.clip(refl[on] * np.exp(amp[on] * field), 0.0, 1.0)
        return refl
