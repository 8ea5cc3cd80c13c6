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

Styles other than ``classic`` (``--styles``) are timed with each sensor's per-sequence draws, as
``dsnet synth --style`` renders them; ``--sensors`` picks the LiDARs.

Run: ``.venv/bin/python bench/bench_synth.py [--sensors hdl64,vlp16] [--styles classic,junction]``.
"""

from __future__ import annotations

import argparse
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
from dsnet_core.synth import SENSORS, SynthConfig, plan_sequence  # noqa: E402
from dsnet_core.synth.log import child_seed, sequence_seed  # noqa: E402
from dsnet_core.synth.render import Renderer  # noqa: E402
from dsnet_core.synth.styles import STYLES  # noqa: E402
from dsnet_core.synth.variation import choose_setup  # noqa: E402

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


def bench(sensor: str, style: str, tmp: Path) -> None:
    setup = choose_setup(child_seed(sequence_seed(0, 0), 2), style, sensor)
    spec = setup.spec
    t0 = time.perf_counter()
    plan = plan_sequence(0, 0, REPEATS, SynthConfig(sensor=sensor), setup)
    plan_ms = 1000.0 * (time.perf_counter() - t0)
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
        f"{style:>11} {sensor:>10}: {spec.rays} rays, {scan.shape[0]} points | "
        f"render {gen_ms:.1f} ms/scan CPU ({gen_wall:.1f} ms wall) "
        f"(world {plan_ms:.0f} ms + raster setup {setup_ms:.0f} ms once per sequence) | "
        f"read-back {read_ms:.2f} ms "
        f"→ ×{gen_ms / read_ms:.0f} | numpy ground-plane pass {plane_ms:.2f} ms → ×{gen_ms / plane_ms:.1f}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sensors", default=",".join(SENSORS), help="comma-separated LiDAR presets")
    parser.add_argument("--styles", default="classic", help=f"comma-separated styles of {sorted(STYLES)}")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        for style in args.styles.split(","):
            for sensor in args.sensors.split(","):
                bench(sensor, style, Path(tmp))


if __name__ == "__main__":
    main()
