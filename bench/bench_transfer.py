"""Transfer: how DS-Net models label streets, sensors and a generator they were not trained on.

Three held-out cells of ``dsnet synth``, generated here (deterministic per seed; none of their seeds,
and for the last two none of their styles or sensors, reach training with the ``TRAIN_STYLES`` /
``TRAIN_SENSORS`` stream below):

- ``seeds``: training styles and sensors, new seeds;
- ``styles``: crossroads / T-junctions and parking lots, which training never draws;
- ``sensors``: the VLP-32C and the 32-beam nuScenes-like pattern, which training never draws.

Each has 4–5 sequences of 10 frames. A fourth cell, ``validation``, is the second generator of
``../shared/validation/`` (written independently of ``dsnet synth``: other scene composition,
shapes, sizes and remission; an HDL-64-like sensor): ``VALIDATION_SEQUENCES`` seeds of 20 frames.
It is reported beside the synthetic cells, never instead of them, and nothing trains or selects
on it; the cell is left out, with a message, when that folder is absent.

Every (model, cell) labels the cell through the real stages with ``bench/bench_methods.py`` rows
(k = 1 + track with the 3D checkpoint, k = 2 + stitch with the 4D one, optionally ``--tta 4``), in
its own process, without the ``refine`` stage unless ``--refine`` (the model's own quality). This
script collects official-mode mIoU, PQ, PQ^Th, PQ^St, LSTQ, every class's IoU and the semantic
confusion matrix into four tables: the scores, the per-class IoU, the means over the synthetic
cells and over the other generator, and the top confusions (for each ground-truth class, the share
of its points labelled right and its most frequent wrong classes).

Run: ``OMP_NUM_THREADS=1 .venv/bin/python bench/bench_transfer.py --out DIR
--model old=OLD_3D:OLD_4D --model new=NEW_3D:NEW_4D [--rows k1,k2] [--cells seeds,validation]``
(a model's 4D checkpoint serves the k = 2 rows; without ``:4D`` the 3D one does). Writes
``DIR/transfer.json`` and ``DIR/transfer.md``; the run stores under ``DIR/<model>/<cell>/`` are
kept and reused while current.

The training stream that keeps the synthetic cells held out::

    dsnet train dsnet --stream N --stream-styles classic,residential,arterial,downtown,country \\
        --stream-sensors hdl64,ouster64,ouster128,vlp16 ...
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

BENCH = Path(__file__).resolve().parent
REPO = BENCH.parent
VALIDATION = next(
    (p / "shared" / "validation" for p in REPO.parents if (p / "shared" / "validation").is_dir()),
    REPO.parent / "shared" / "validation",
)  # ../shared/validation beside the checkout (or beside a folder of worktrees)
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
OTHER = "validation"
#: the other generator's cell: (sequence number, seed) per sequence, VALIDATION_FRAMES frames each
VALIDATION_SEQUENCES = ((8, 123), (9, 124), (10, 125), (11, 126))
VALIDATION_FRAMES = 20
ALL_CELLS = (*CELLS, OTHER)
#: table row → (bench_methods row, which checkpoint: 1 = the 3D model, 2 = the 4D one)
ROWS = {
    "k1": ("dsnet-k1-track", 1),
    "k1-tta4": ("dsnet-k1-tta4", 1),
    "k2": ("dsnet-k2-stitch", 2),
    "k2-tta4": ("dsnet-k2-tta4", 2),
}
METRICS = ("miou", "pq", "pq_things", "pq_stuff", "lstq")
TOP = 3  # wrong classes listed per ground-truth class


def make_cell(root: Path, name: str) -> Path:
    """Generate cell ``name`` under ``root/name`` unless the same one is there."""
    out = root / name
    stamp = out / "bench_cell.json"
    if name == OTHER:
        want = {"generator": "other", "sequences": VALIDATION_SEQUENCES, "frames": VALIDATION_FRAMES}
    else:
        seed, first, setups = CELLS[name]
        want = {"seed": seed, "first": first, "setups": setups, "frames": FRAMES}
    if stamp.exists() and json.loads(stamp.read_text()) == json.loads(json.dumps(want)):
        return out
    if name == OTHER:
        sys.path.insert(0, str(VALIDATION))
        import other_generator

        for seq, seed in VALIDATION_SEQUENCES:
            other_generator.write_sequence(str(out), seq=seq, n_frames=VALIDATION_FRAMES, seed=seed)
    else:
        from dsnet_core.synth import generate_log

        for i, (style, sensor) in enumerate(setups):
            generate_log(out, sequences=1, frames=FRAMES, seed=seed, sensor=sensor, style=style,
                         first_sequence=first + i, overwrite=True)  # fmt: skip
    stamp.write_text(json.dumps(want) + "\n")
    return out


def run_rows(out: Path, data: Path, ckpt: str, keys: list[str], refine: bool) -> dict:
    """``bench_methods.py`` rows ``keys`` on ``data`` with DS-Net checkpoint ``ckpt``; their results."""
    methods = [ROWS[k][0] for k in keys]
    cmd = [sys.executable, str(BENCH / "bench_methods.py"), "--out", str(out), "--data", str(data)]
    cmd += ["--rows", ",".join(methods), "--checkpoint-dsnet", ckpt]
    cmd.append("--refine" if refine else "--no-refine")
    res = subprocess.run(cmd, capture_output=True, text=True)
    if res.returncode != 0:
        raise SystemExit(f"{out}: bench_methods failed:\n{res.stderr[-3000:]}")
    rows = json.loads((out / "bench_methods.json").read_text())["rows"]
    return {k: rows[ROWS[k][0]] for k in keys}


def confusions(conf: np.ndarray, names: list[str], top: int = TOP) -> dict[str, dict]:
    """For each ground-truth class with points: the share labelled right and its ``top`` most
    frequent wrong classes.

    Args:
        conf: ``(C, C)`` points per (predicted, ground-truth) train class; class 0 is ignored.
        names: class name per train id.

    Returns:
        ``{gt name: {"points": n, "right": share, "wrong": [(pred name, share), ...]}}``, shares of
        the class's points (unlabelled predictions included in the total).
    """
    out = {}
    for g in range(1, conf.shape[1]):
        n = int(conf[:, g].sum())
        if n == 0:
            continue
        col = conf[:, g].astype(np.float64) / n
        wrong = [(names[p], float(col[p])) for p in np.argsort(-col, kind="stable") if p != g and col[p] > 0]
        out[names[g]] = {"points": n, "right": float(col[g]), "wrong": wrong[:top]}
    return out


def _fmt(x: float | None, digits: int = 3) -> str:
    return "–" if x is None else f"{x:.{digits}f}"


def markdown(results: dict) -> str:
    """The four tables of ``results`` (model → cell → row → bench_methods result)."""
    any_scores = next(r["scores"] for c in results.values() for rs in c.values() for r in rs.values())
    names = [n for n in any_scores["class_names"][1:]]
    lines = ["## Scores (official mode)", ""]
    head = ["model", "cell", "row", "mIoU", "PQ", "PQ^Th", "PQ^St", "LSTQ", "s/frame"]
    lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for model, cells in results.items():
        for cell, rows in cells.items():
            for key, r in rows.items():
                s = r["scores"]
                row = [model, cell, key, *(_fmt(s.get(m)) for m in METRICS)]
                row.append(f"{sum(r['s_per_frame'].values()):.2f}")
                lines.append("| " + " | ".join(row) + " |")
    lines += ["", "## Mean over the held-out synthetic cells and the other generator", ""]
    head = ["model", "row", "synth mIoU", "synth PQ", "other mIoU", "other PQ", "other LSTQ"]
    lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for model, cells in results.items():
        keys = list(next(iter(cells.values())))
        for key in keys:
            synth = [cells[c][key]["scores"] for c in cells if c != OTHER and key in cells[c]]
            other = cells.get(OTHER, {}).get(key, {}).get("scores")
            row = [model, key]
            row += [_fmt(float(np.mean([s[m] for s in synth]))) if synth else "–" for m in ("miou", "pq")]
            row += [_fmt(other[m]) if other else "–" for m in ("miou", "pq", "lstq")]
            lines.append("| " + " | ".join(row) + " |")
    lines += ["", "## IoU per class", ""]
    head = ["model", "cell", "row", *names]
    lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for model, cells in results.items():
        for cell, rows in cells.items():
            for key, r in rows.items():
                iou = r["scores"].get("class_iou", {})
                lines.append(
                    "| " + " | ".join([model, cell, key, *(_fmt(iou.get(c), 2) for c in names)]) + " |"
                )
    lines += [
        "",
        "## Top confusions (k1 row, else the first): share of each ground-truth class's points labelled",
        "right, then its most frequent wrong classes",
        "",
    ]
    for model, cells in results.items():
        lines += [
            f"**{model}**",
            "",
            "| ground truth | " + " | ".join(cells) + " |",
            "|---|" + "---|" * len(cells),
        ]
        tables = {}
        for cell, rows in cells.items():
            r = rows.get("k1") or next(iter(rows.values()))
            tables[cell] = confusions(np.asarray(r["scores"]["confusion"]), r["scores"]["class_names"])
        for name in names:
            cols = []
            for cell in cells:
                c = tables[cell].get(name)
                if c is None:
                    cols.append("–")
                    continue
                wrong = ", ".join(f"{p} {100 * f:.0f}" for p, f in c["wrong"] if f >= 0.005)
                cols.append(f"**{100 * c['right']:.0f}**" + (f" · {wrong}" if wrong else ""))
            lines.append(f"| {name} | " + " | ".join(cols) + " |")
        lines.append("")
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--model", action="append", required=True, help="NAME=CKPT_3D[:CKPT_4D] (repeatable)")
    ap.add_argument("--rows", default="k1,k2", help=f"comma-separated, of {', '.join(ROWS)}")
    ap.add_argument(
        "--cells", default=",".join(ALL_CELLS), help=f"comma-separated, of {', '.join(ALL_CELLS)}"
    )
    ap.add_argument("--refine", action="store_true", help="score the labels after refine (default: before)")
    args = ap.parse_args()
    keys = args.rows.split(",")
    if bad := [k for k in keys if k not in ROWS]:
        raise SystemExit(f"unknown rows {bad} (choose from {', '.join(ROWS)})")
    cell_names = args.cells.split(",")
    if bad := [c for c in cell_names if c not in ALL_CELLS]:
        raise SystemExit(f"unknown cells {bad} (choose from {', '.join(ALL_CELLS)})")
    if OTHER in cell_names and not (VALIDATION / "other_generator.py").exists():
        print(f"{VALIDATION} is absent: the {OTHER} cell is left out", flush=True)
        cell_names.remove(OTHER)
    sys.path.insert(0, str(REPO))
    args.out.mkdir(parents=True, exist_ok=True)
    results: dict = {}
    for spec in args.model:
        name, _, paths = spec.partition("=")
        one, _, four = paths.partition(":")
        ckpts = {1: str(Path(one).resolve()), 2: str(Path(four or one).resolve())}
        results[name] = {}
        for cell in cell_names:
            data = make_cell(args.out / "logs", cell)
            results[name][cell] = {}
            for k in (1, 2):
                mine = [key for key in keys if ROWS[key][1] == k]
                if mine:
                    results[name][cell].update(
                        run_rows(args.out / name / cell / f"k{k}", data, ckpts[k], mine, args.refine)
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
