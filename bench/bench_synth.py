"""Synthetic-log generator speed: milliseconds per scan, against baselines measured in the same run.

For each sensor the scan is rendered (ray cast + returns) ``REPEATS`` times after a warm-up (the
first call also loads or compiles the numba kernels). Two baselines, timed on the same scan:

* ``read``: reading that scan and its labels back from disk (``read_scan`` + ``read_label``), the
  cost any consumer of a real log pays per frame;
* ``plane``: the cheapest vectorised cast imaginable, a numpy pass that rotates every ray and
  intersects it with the ground plane only (no objects, no classes, no noise).

Times are CPU times of this process (``time.process_time``, median of ``REPEATS``): the kernels run
single-threaded, so this is the cost on one core and stays meaningful on a machine shared with other
jobs; the wall-clock median is printed beside it.

Run: ``.venv/bin/python bench/bench_synth.py``.
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # one core: also for the numpy baseline's BLAS

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from dsnet_core.io import kitti  # noqa: E402
from dsnet_core.synth import SynthConfig, get_sensor, plan_sequence  # noqa: E402
from dsnet_core.synth.render import Renderer  # noqa: E402

REPEATS = 10


def _median_ms(fn, repeats: int = REPEATS) -> tuple[float, float]:
    """(CPU, wall) medians in milliseconds."""
    cpu, wall = [], []
    for _ in range(repeats):
        c0, w0 = time.process_time(), time.perf_counter()
        fn()
        cpu.append(time.process_time() - c0)
        wall.append(time.perf_counter() - w0)
    return 1000.0 * float(np.median(cpu)), 1000.0 * float(np.median(wall))


def bench(sensor: str, tmp: Path) -> None:
    spec = get_sensor(sensor)
    plan = plan_sequence(0, 0, REPEATS, SynthConfig(sensor=sensor))
    t0 = time.perf_counter()
    renderer = Renderer(plan.scene, spec, plan.poses[:, :2, 3])
    setup_ms = 1000.0 * (time.perf_counter() - t0)
    rng = np.random.default_rng(0)
    scan, label = renderer.render(plan.poses[0], 0.0, rng)  # warm-up
    frame = iter(range(10**9))

    def render() -> None:
        i = next(frame) % REPEATS
        renderer.render(plan.poses[i], float(plan.times[i]), rng)

    gen_ms, gen_wall = _median_ms(render)
    kitti.write_scan(tmp / "s.bin", scan)
    kitti.write_label(tmp / "s.label", label)
    read_ms, _ = _median_ms(
        lambda: kitti.read_label(tmp / "s.label", kitti.read_scan(tmp / "s.bin").shape[0])
    )
    dirs, pose = renderer.dirs, plan.poses[0]

    def plane() -> None:
        world = dirs @ pose[:3, :3].T
        t = np.where(world[:, 2] < 0, -pose[2, 3] / np.minimum(world[:, 2], -1e-9), np.inf)
        _ = dirs * t[:, None]

    plane_ms, _ = _median_ms(plane)
    print(
        f"{sensor}: {spec.rays} rays, {scan.shape[0]} points | render {gen_ms:.1f} ms/scan CPU "
        f"({gen_wall:.1f} ms wall) "
        f"(scene raster setup {setup_ms:.0f} ms once per sequence) | read-back {read_ms:.2f} ms "
        f"→ ×{gen_ms / read_ms:.0f} | numpy ground-plane pass {plane_ms:.2f} ms → ×{gen_ms / plane_ms:.1f}"
    )


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        for sensor in ("hdl64", "vlp32"):
            bench(sensor, Path(tmp))


if __name__ == "__main__":
    main()
