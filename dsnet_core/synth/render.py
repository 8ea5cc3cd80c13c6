"""Renders one LiDAR sweep of a scene from an ego pose: cast the rays, then turn hits into returns."""

from __future__ import annotations

import numpy as np

from dsnet_core.synth.ground import ground_hits_raster
from dsnet_core.synth.raycast import GROUND_REFLECTIVITY, bin_primitives, cast_rays, ground_hits_frenet
from dsnet_core.synth.scene import Scene
from dsnet_core.synth.sensor import LidarSpec, simulate_returns

AZIMUTH_BINS = 720
GRID_RES = 1.0  # bilinear Frenet lookup: error ≈ curvature · res² / 8 < 1 cm


class Renderer:
    """Casts ``spec``'s rays into ``scene`` from poses near ``path_xy``.

    Args:
        scene: the world.
        spec: the LiDAR.
        path_xy: ``(F, 2)`` ego positions (metres); the Frenet raster covers them ± the max range.
    """

    def __init__(self, scene: Scene, spec: LidarSpec, path_xy: np.ndarray) -> None:
        self.scene, self.spec = scene, spec
        self.dirs = spec.directions()
        margin = spec.max_range + 2.0
        lo = path_xy.min(axis=0) - margin
        hi = path_xy.max(axis=0) + margin
        nx, ny = (np.ceil((hi - lo) / GRID_RES).astype(int) + 1).tolist()
        self.ground_refl = (
            GROUND_REFLECTIVITY if scene.ground_reflectivity is None else scene.ground_reflectivity
        )
        if scene.ground is not None:  # a styled street: its painted raster replaces the Frenet ground
            self.ground = scene.ground.kernel_args()
            return
        grid_s, grid_d = scene.road.frenet_grid(lo[0], lo[1], nx, ny, GRID_RES)
        lay = scene.layout
        meta = np.array([lo[0], lo[1], GRID_RES, lay.s0, lay.ds, lay.lane_width])
        self.ground = (grid_s, grid_d, meta, lay.edges, lay.classes, lay.lanes)

    def cast(
        self, pose: np.ndarray, t: float, salt: float = 0.0, rng: np.random.Generator | None = None
    ) -> tuple[np.ndarray, ...]:
        """Geometric hits of every ray from sensor pose ``pose`` ``(4, 4)`` (sensor → world) at time ``t``;
        ``salt`` varies the foliage penetration draw, ``rng`` the grass of a scene with a
        :class:`~dsnet_core.synth.surface.Surface` (a fixed one when None).

        Returns:
            range ``(R,)`` (inf: no hit), raw semantic ``(R,) int32``, instance ``(R,) int32``,
            |cos incidence| ``(R,)``, reflectivity ``(R,)``; rays in :meth:`LidarSpec.directions` order.
        """
        p = self.scene.primitives_at(t)
        origin = np.ascontiguousarray(pose[:3, 3])
        rot = np.ascontiguousarray(pose[:3, :3])
        max_range = self.spec.max_range
        cull = bin_primitives(*origin, p.kind, p.center, p.half, max_range, AZIMUTH_BINS)
        prims = (p.kind, p.center, p.yaw, p.half, p.semantic, p.instance, p.reflectivity)
        if self.scene.ground is None:
            hits = ground_hits_frenet(origin, rot, self.dirs, self.ground)
        else:
            hits = ground_hits_raster(origin, rot, self.dirs, *self.ground, max_range + 1.0)
        surface = self.scene.surface
        if surface is not None:
            world_dirs = self.dirs @ rot.T
            hits = surface.roughen(origin, world_dirs, hits, rng or np.random.default_rng(0))
        out = cast_rays(
            origin,
            rot,
            self.dirs,
            prims,
            cull,
            AZIMUTH_BINS,
            hits,
            self.ground_refl,
            max_range + 1.0,
            salt,
        )
        if surface is None:
            return out
        hit_range, sem, inst, cos, refl = out
        return hit_range, sem, inst, cos, surface.patch(origin, world_dirs, hit_range, sem, refl)

    def render(self, pose: np.ndarray, t: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """One sweep.

        Returns:
            scan ``(N, 4) float32`` (x, y, z in the sensor frame, metres; remission) and label
            ``(N,) uint32`` (raw semantic | instance << 16).
        """
        hit_range, sem, inst, cos, refl = self.cast(pose, t, float(rng.uniform(0.0, 1000.0)), rng)
        return simulate_returns(self.spec, self.dirs, hit_range, cos, refl, sem, inst, rng)
