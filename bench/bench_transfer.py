"""Transfer: how DS-Net models label streets and sensors they were not trained on.

Three held-out cells, generated here (deterministic per seed; none of their seeds, and for the last
two none of their styles or sensors, reach training with the ``TRAIN_STYLES`` / ``TRAIN_SENSORS``
stream below):

- ``seeds``: training styles and sensors, new seeds;
- ``styles``: crossroads / T-junctions and parking lots, which training never draws;
- ``sensors``: the VLP-32C and the 32-beam nuScenes-like pattern, which training never draws.

Each cell has 4–5 sequences of 10 frames. Every (model, cell) labels the cell through the real
stages with ``bench/bench_methods.py`` rows (k = 1 + track, k = 2 + stitch, and the same with
``--tta 4``), in its own process; this script collects official-mode mIoU, PQ, PQ^Th, PQ^St, LSTQ
and the ground classes' IoU into one table.

Run: ``OMP_NUM_THREADS=1 .venv/bin/python bench/bench_transfer.py --out DIR
--model old=OLD_3D:OLD_4D --model new=NEW_3D:NEW_4D [--rows k1,k1-tta4,k2] [--cells seeds,styles]``
(a model's 4D checkpoint serves the k = 2 rows; without ``:4D`` the 3D one does). Writes
``DIR/transfer.json`` and ``DIR/transfer.md``; the run stores under ``DIR/<model>/<cell>/`` are
kept and reused while current.

The training stream that keeps these cells held out::

    dsnet train dsnet --stream N --stream-styles classic,residential,arterial,downtown,country \\
        --stream-sensors hdl64,ouster64,ouster128,vlp16 ...
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

TRAIN_STYLES = ("classic", "residential", "arterial", "downtown", "country")
TRAIN_SENSORS = ("hdl64", "ouster64", "ouster128", "vlp16")
FRAMES = 10
#: cell → (seed, first sequence, [(style, sensor) per sequence])
CELLS: dict[str, tuple[int, int, list[tuple[str, str]]]] = {
    "seeds": (
        303,
        60,
        [
            ("residential", "hdl64"),
            ("arterial", "ouster64"),
            ("downtown", "vlp16"),
            ("country", "hdl64"),
            ("classic", "ouster128"),
        ],
    ),
    "styles": (
        404,
        70,
        [("junction", "hdl64"), ("junction", "ouster64"), ("parking_lot", "hdl64"), ("parking_lot", "vlp16")],
    ),
    "sensors": (
        505,
        80,
        [
            ("residential", "vlp32"),
            ("arterial", "vlp32"),
            ("downtown", "nuscenes32"),
            ("country", "nuscenes32"),
        ],
    ),
}
#: table row → (bench_methods row, which checkpoint: 1 = the 3D model, 2 = the 4D one)
ROWS = {
    "k1": ("dsnet-k1-track", 1),
    "k1-tta4": ("dsnet-k1-tta4", 1),
    "k2": ("dsnet-k2-stitch", 2),
    "k2-tta4": ("dsnet-k2-tta4", 2),
}
GROUND = ("road", "sidewalk", "parking", "other-ground", "terrain", "vegetation", "building")
BENCH = Path(__file__).resolve().parent


def make_cell(root: Path, name: str) -> Path:
    """Generate cell ``name`` under ``root/name`` unless the same one is there."""
    from dsnet_core.synth import generate_log

    seed, first, setups = CELLS[name]
    out = root / name
    stamp = out / "bench_cell.json"
    want = {"seed": seed, "first": first, "setups": setups, "frames": FRAMES}
    if stamp.exists() and json.loads(stamp.read_text()) == json.loads(json.dumps(want)):
        return out
    for i, (style, sensor) in enumerate(setups):
        generate_log(out, sequences=1, frames=FRAMES, seed=seed, sensor=sensor, style=style,
                     first_sequence=first + i, overwrite=True)  # fmt: skip
    stamp.write_text(json.dumps(want) + "\n")
    return out


def run_rows(out: Path, data: Path, ckpt: str, keys: list[str]) -> dict:
    """``bench_methods.py`` rows ``keys`` on ``data`` with DS-Net checkpoint ``ckpt``; their results."""
    methods = [ROWS[k][0] for k in keys]
    cmd = [sys.executable, str(BENCH / "bench_methods.py"), "--out", str(out), "--data", str(data)]
    cmd += ["--rows", ",".join(methods), "--checkpoint-dsnet", ckpt]
    res = subprocess.run(cmd, capture_output=True, text=True)
    if res.returncode != 0:
        raise SystemExit(f"{out}: bench_methods failed:\n{res.stderr[-3000:]}")
    rows = json.loads((out / "bench_methods.json").read_text())["rows"]
    return {k: rows[ROWS[k][0]] for k in keys}


def markdown(results: dict) -> str:
    head = ["model", "cell", "row", "mIoU", "PQ", "PQ^Th", "PQ^St", "LSTQ", "s/frame", *GROUND]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for model, cells in results.items():
        for cell, rows in cells.items():
            for key, r in rows.items():
                s = r["scores"]
                iou = s.get("class_iou", {})
                cells_ = [model, cell, key] + [
                    f"{s[m]:.3f}" if s.get(m) is not None else "–"
                    for m in ("miou", "pq", "pq_things", "pq_stuff", "lstq")
                ]
                cells_.append(f"{sum(r['s_per_frame'].values()):.2f}")
                cells_ += [f"{iou[c]:.2f}" if iou.get(c) is not None else "–" for c in GROUND]
                lines.append("| " + " | ".join(cells_) + " |")
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--model", action="append", required=True, help="NAME=CKPT_3D[:CKPT_4D] (repeatable)")
    ap.add_argument("--rows", default="k1,k1-tta4,k2", help=f"comma-separated, of {', '.join(ROWS)}")
    ap.add_argument("--cells", default=",".join(CELLS), help=f"comma-separated, of {', '.join(CELLS)}")
    args = ap.parse_args()
    keys = args.rows.split(",")
    if bad := [k for k in keys if k not in ROWS]:
        raise SystemExit(f"unknown rows {bad} (choose from {', '.join(ROWS)})")
    sys.path.insert(0, str(BENCH.parent))
    args.out.mkdir(parents=True, exist_ok=True)
    results: dict = {}
    for spec in args.model:
        name, _, paths = spec.partition("=")
        one, _, four = paths.partition(":")
        ckpts = {1: str(Path(one).resolve()), 2: str(Path(four or one).resolve())}
        results[name] = {}
        for cell in args.cells.split(","):
            data = make_cell(args.out / "logs", cell)
            results[name][cell] = {}
            for k in (1, 2):
                mine = [key for key in keys if ROWS[key][1] == k]
                if mine:
                    results[name][cell].update(
                        run_rows(args.out / name / cell / f"k{k}", data, ckpts[k], mine)
                    )
            for key in keys:
                s = results[name][cell][key]["scores"]
                print(
                    f"{name} {cell} {key}: mIoU {s['miou']:.3f} PQ {s['pq']:.3f} LSTQ {s['lstq']:.3f}",
                    flush=True,
                )
            (args.out / "transfer.json").write_text(json.dumps(results, indent=2) + "\n")
    md = markdown(results)
    (args.out / "transfer.md").write_text(md)
    print()
    print(md)


if __name__ == "__main__":
    main()
