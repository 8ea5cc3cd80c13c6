"""Own sparse convolution vs spconv (CPU, one thread) on one synthetic frame, same weights.

A stack of the layer types the Cylinder3D backbone uses, at base widths ``w`` = 4 (tiny) and
32 (paper): 1×3×3 (16→w), 3×1×3 (w→w), 3×3×3 (w→w) submanifold at full resolution, a strided
3×3×3 (w→2w), a 3×3×3 submanifold (2w→2w) at half resolution and the inverse conv (2w→w).
Each (implementation, width) runs in its own subprocess, so peak RSS is its own. Prints forward and
train-step (forward + backward) medians, their ratios own/spconv, the max abs difference of the
outputs (float32), and peak memory.

spconv is optional: install it next to the venv (``pip install --target DIR spconv==2.3.8``) and
pass ``--spconv-path DIR``; without it only our numbers are printed.

    .venv/bin/python bench/bench_sparse_conv.py --spconv-path /work/train-runs/spconv-pkgs
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
ROOT = Path(__file__).resolve().parents[1]


def make_frame(path: Path) -> None:
    from dsnet_core.synth import generate_log

    generate_log(path, sequences=1, frames=1, seed=7, sensor="hdl64")


def layer_specs(w: int):
    # (kind, kernel, cin, cout)
    return [
        ("subm", (1, 3, 3), 16, w),
        ("subm", (3, 1, 3), w, w),
        ("subm", (3, 3, 3), w, w),
        ("down", (3, 3, 3), w, 2 * w),
        ("subm2", (3, 3, 3), 2 * w, 2 * w),
        ("inv", (3, 3, 3), 2 * w, w),
    ]


def _peak_reset() -> None:
    with open("/proc/self/clear_refs", "w") as f:
        f.write("5")


def _peak_mb() -> float:
    for line in open("/proc/self/status"):
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    return float("nan")


_NAIVE = [False]


def build(impl: str, width: int, log_root: str, spconv_path: str | None):
    """(run(feats) -> out features, layers, input feats, frame info) for one implementation."""
    import numpy as np
    import torch

    torch.set_num_threads(1)
    sys.path.insert(0, str(ROOT))
    from dsnet_core.io.semantickitti import SemanticKittiReader
    from dsnet_core.model.cylinder import CylinderGrid, voxelize
    from dsnet_core.model.sparse_conv import SparseConv3d, SparseInverseConv3d, SparseTensor, SubMConv3d

    reader = SemanticKittiReader(log_root)
    pts = torch.from_numpy(reader.scan(reader.frames(reader.sequences()[0])[0]))
    grid = CylinderGrid()
    vox = voxelize([pts], grid)
    coords = vox.coords
    g = torch.Generator().manual_seed(0)
    feats = torch.randn(coords.shape[0], 16, generator=g)
    specs = layer_specs(width)
    weights = [
        torch.randn(int(np.prod(k)), ci, co, generator=g) / np.sqrt(ci * np.prod(k)) for _, k, ci, co in specs
    ]

    if impl in ("own", "naive"):
        layers = []
        for (kind, k, ci, co), wt in zip(specs, weights, strict=True):
            if kind == "down":
                layer = SparseConv3d(ci, co, k, stride=2, padding=1, indice_key="d")
            elif kind == "inv":
                layer = SparseInverseConv3d(ci, co, k, indice_key="d")
            else:
                layer = SubMConv3d(ci, co, k)
            layer.weight.data.copy_(wt)
            layers.append(layer)

        if impl == "naive":  # the same rulebooks through plain autograd (keeps every gathered copy)
            from dsnet_core.model import sparse_conv as sc

            def naive_conv(x, weight, book):
                out = x.new_zeros((book.n_out, weight.shape[2]))
                for k, (i, o) in enumerate(book.pairs(weight.shape[0])):
                    if i.numel():
                        out = out.index_add(0, o, x[i] @ weight[k])
                return out

            if not hasattr(sc, "_own_sparse_conv"):
                sc._own_sparse_conv = sc.sparse_conv
                sc.sparse_conv = lambda x, w, b: (naive_conv if _NAIVE[0] else sc._own_sparse_conv)(x, w, b)

        def run(x_feats):
            _NAIVE[0] = impl == "naive"
            try:
                x = SparseTensor(x_feats, coords, grid.size, 1)
                for layer in layers:
                    x = layer(x)
                return x.features
            finally:
                _NAIVE[0] = False

    else:
        sys.path.append(spconv_path)
        import spconv.pytorch as spconv

        _patch_spconv_cpu_stream()

        layers = []
        for (kind, k, ci, co), wt in zip(specs, weights, strict=True):
            pad = tuple(x // 2 for x in k)
            if kind == "down":
                layer = spconv.SparseConv3d(ci, co, k, stride=2, padding=1, bias=False, indice_key="d")
            elif kind == "inv":
                layer = spconv.SparseInverseConv3d(ci, co, k, bias=False, indice_key="d")
            else:
                key = f"s{kind}{k}"
                layer = spconv.SubMConv3d(ci, co, k, padding=pad, bias=False, indice_key=key)
            # ours: (K, in, out), taps row-major; spconv 2.x: (out, k0, k1, k2, in)
            layer.weight.data.copy_(wt.reshape(*k, ci, co).permute(4, 0, 1, 2, 3))
            layers.append(layer)
        sp_coords = coords.to(torch.int32)

        def run(x_feats):
            x = spconv.SparseConvTensor(x_feats, sp_coords, list(grid.size), 1)
            for layer in layers:
                x = layer(x)
            return x.features

    return run, layers, feats, {"voxels": int(coords.shape[0]), "points": int(pts.shape[0])}


def _patch_spconv_cpu_stream() -> None:
    """spconv 2.3.8's CPU backward asks ``torch.cuda.current_stream()`` (through
    ``spconv.pytorch.cppcore.get_current_stream``) even for CPU tensors, which fails without a CUDA
    driver; on a CPU-only machine hand it stream 0 (the value is unused by its CPU kernels)."""
    import torch

    if torch.cuda.is_available():
        return
    for name, mod in list(sys.modules.items()):
        if name.startswith("spconv") and hasattr(mod, "get_current_stream"):
            mod.get_current_stream = lambda: 0


def _step(run, layers, feats) -> None:
    f = feats.clone().requires_grad_(True)
    for layer in layers:
        layer.weight.grad = None
    run(f).square().mean().backward()


def worker(impl: str, width: int, log_root: str, spconv_path: str | None, repeats: int) -> dict:
    """Outputs and peak memory of one implementation (its own process)."""
    import numpy as np
    import torch

    run, layers, feats, info = build(impl, width, log_root, spconv_path)
    with torch.no_grad():
        out = run(feats)
    if impl != "spconv":  # count our cached scratch buffers in the train step's peak
        from dsnet_core.model.sparse_conv import release_workspace

        release_workspace()
    _peak_reset()
    base = _peak_mb()
    try:
        _step(run, layers, feats)
        train_ok = True
    except RuntimeError as exc:  # spconv's CPU build: backward asks for a CUDA stream
        train_ok = f"fails: {str(exc).splitlines()[0][:60]}"
    peak = _peak_mb() - base
    np.save(Path(log_root) / f"out_{impl}_{width}.npy", out.numpy())
    return {**info, "peak_mb": peak, "train_ok": train_ok}


def timing_worker(impls: list[str], width: int, log_root: str, spconv_path: str | None, repeats: int) -> dict:
    """Forward and train-step medians of all implementations, interleaved (one process, so that
    a machine's changing load hits every implementation alike)."""
    import numpy as np
    import torch

    built = {impl: build(impl, width, log_root, spconv_path) for impl in impls}
    fwd = {impl: [] for impl in impls}
    train: dict = {impl: [] for impl in impls}
    for _ in range(repeats + 1):  # the first round warms up
        for impl, (run, layers, feats, _) in built.items():
            t = time.process_time()
            with torch.no_grad():
                run(feats)
            fwd[impl].append(time.process_time() - t)
            if train[impl] is None:
                continue
            t = time.process_time()
            try:
                _step(run, layers, feats)
                train[impl].append(time.process_time() - t)
            except RuntimeError:
                train[impl] = None
    return {
        impl: {
            "fwd_s": float(np.median(fwd[impl][1:])),
            "train_s": float(np.median(train[impl][1:])) if train[impl] else None,
        }
        for impl in impls
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--spconv-path", default=None, help="folder where spconv is installed (pip --target)")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--worker", nargs=3, help=argparse.SUPPRESS)
    ap.add_argument("--timing", nargs=3, help=argparse.SUPPRESS)
    ap.add_argument("--log", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.timing:
        impls, width, log_root = args.timing
        res = timing_worker(impls.split(","), int(width), log_root, args.spconv_path, args.repeats)
        print(json.dumps(res))
        return
    if args.worker:
        impl, width, log_root = args.worker
        print(json.dumps(worker(impl, int(width), log_root, args.spconv_path, args.repeats)))
        return
    import numpy as np

    with tempfile.TemporaryDirectory() as tmp:
        make_frame(Path(tmp))
        impls = ["own", "naive"] + (["spconv"] if args.spconv_path else [])
        res = {}
        for width in (4, 32):
            for impl in impls:
                cmd = [
                    sys.executable,
                    __file__,
                    "--worker",
                    impl,
                    str(width),
                    tmp,
                    "--repeats",
                    str(args.repeats),
                ]
                if args.spconv_path:
                    cmd += ["--spconv-path", args.spconv_path]
                done = subprocess.run(cmd, capture_output=True, text=True, check=True, cwd=ROOT)
                res[impl, width] = json.loads(done.stdout.strip().splitlines()[-1])
            cmd = [sys.executable, __file__, "--timing", ",".join(impls), str(width), tmp]
            cmd += ["--repeats", str(args.repeats)]
            if args.spconv_path:
                cmd += ["--spconv-path", args.spconv_path]
            done = subprocess.run(cmd, capture_output=True, text=True, check=True, cwd=ROOT)
            for impl, times in json.loads(done.stdout.strip().splitlines()[-1]).items():
                res[impl, width].update(times)
        first = res["own", 4]
        print(
            f"frame: {first['points']} points, {first['voxels']} voxels; 1 thread; "
            f"process CPU time, median of {args.repeats}, interleaved (a shared machine inflates wall time)"
        )
        if not args.spconv_path:
            print("spconv not given (--spconv-path): own vs naive only")
        head = (
            "width",
            "impl",
            "fwd s",
            "train s",
            "train peak MB",
            "fwd own/x",
            "train own/x",
            "max|own-x|",
        )
        print(" ".join(f"{h:>13}" for h in head))
        for width in (4, 32):
            own = res["own", width]
            for impl in impls:
                r = res[impl, width]
                train = r["train_s"]
                ok = isinstance(train, float)
                if not ok:
                    train = r["train_ok"]
                cells = [str(width), impl, f"{r['fwd_s']:.3f}"]
                cells.append(f"{train:.3f}" if ok else "fails")
                cells.append(f"{r['peak_mb']:.0f}" if ok else "-")
                cells.append(f"{own['fwd_s'] / r['fwd_s']:.2f}x")
                cells.append(f"{own['train_s'] / train:.2f}x" if ok else "-")
                a = np.load(Path(tmp) / f"out_own_{width}.npy")
                b = np.load(Path(tmp) / f"out_{impl}_{width}.npy")
                cells.append(f"{np.abs(a - b).max():.1e}" if a.shape == b.shape else f"{b.shape} rows")
                print(" ".join(f"{c:>13}" for c in cells))
                if not ok:
                    print(f"{'':>13} {impl} train step {train}")


if __name__ == "__main__":
    main()
