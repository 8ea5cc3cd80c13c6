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

Two real cells: ``pandaset``, sequences 31 and 32 (20 frames, Pandar64) of PandaSet scene 002 in
``../shared/real/pandaset-002/`` (unpacked with its ``unpack.py`` into ``DIR/logs/pandaset-002``
when not there; validation only: sequence 30, the one that may be trained on, is never labelled
here, and nothing selects on these cells), with the coordinates as stored (rounded to 1 cm); and
``pandaset-dq``, the same frames dequantised (every coordinate moved by a seeded uniform ±5 mm,
``DQ_SEED``), which rounding to 1 cm turns back into ``pandaset``. Both are left out, with a
message, when that folder is absent. PandaSet 31 + 32 lacks 8 of the 19 classes (its README says 9:
it counts terrain, 62 points, as absent): beside the official means (absent classes count 0) every
score row has the means over the classes present (``bench/_present.py``: a class is present when
the cell's ground truth has points of it).

Stability (``bench/_stability.py``): for every (model, cell, row) the cell's log is copied with every
coordinate moved by uniform ±5 mm (seed ``JITTER_SEED``), the row's pipeline runs on it as far as
``infer``, and the column ``flip`` is the share of points whose predicted class (the network's,
before shifting, tracking and refine) differs from the ``infer`` stage of the row's own store
(at k = 2 over the points of each 2-scan volume); a stability table says how many of the flipped
predictions were unsure and, at k = 1, how many flipped points stayed in their cylinder cell;
``--no-stability`` leaves it out.

Every (model, cell) labels the cell through the real stages with ``bench/bench_methods.py`` rows
(k = 1 + track with the 3D checkpoint, k = 2 + stitch with the 4D one, optionally ``--tta 4``), in
its own process, without the ``refine`` stage unless ``--refine`` (the model's own quality). This
script collects official-mode mIoU, PQ, PQ^Th, PQ^St, LSTQ, every class's IoU and PQ and the
semantic confusion matrix into tables: the scores (with present-class means and flips), the scores
before refine (with ``--refine``), stability, the means over the synthetic cells, the other
generator and PandaSet, the per-class IoU and PQ, and per row the top confusions (for each
ground-truth class, the share of its points labelled right and its most frequent wrong classes).

Run: ``OMP_NUM_THREADS=1 .venv/bin/python bench/bench_transfer.py --out DIR
--model old=OLD_3D:OLD_4D --model new=NEW_3D:NEW_4D [--rows k1,k2] [--cells seeds,validation,pandaset]
[--refine]`` (a model's 4D checkpoint serves the k = 2 rows; without ``:4D`` the 3D one does;
``--model bundled`` takes the models ``dsnet label`` takes without ``--checkpoint``). With
``--refine`` (``dsnet label``'s default) the labels are scored after refine and, from the same
stores, before it. Writes
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
from _present import present_scores
from _stability import JITTER_MM, LOW_MARGIN

BENCH = Path(__file__).resolve().parent
REPO = BENCH.parent
VALIDATION = next(
    (p / "shared" / "validation" for p in REPO.parents if (p / "shared" / "validation").is_dir()),
    REPO.parent / "shared" / "validation",
)  # ../shared/validation beside the checkout (or beside a folder of worktrees)
PANDASET_SOURCE = next(
    (
        p / "shared" / "real" / "pandaset-002"
        for p in REPO.parents
        if (p / "shared" / "real" / "pandaset-002").is_dir()
    ),
    REPO.parent / "shared" / "real" / "pandaset-002",
)
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
PANDASET, PANDASET_DQ = "pandaset", "pandaset-dq"
REAL = (PANDASET, PANDASET_DQ)
PANDASET_SEQUENCES = ("31", "32")  # validation only; 30 may be trained on and is never labelled here
DQ_SEED = 1  # the dequantising jitter of pandaset-dq (the stability jitter has its own seed)
ALL_CELLS = (*CELLS, OTHER, *REAL)
#: table row → (bench_methods row, which checkpoint: 1 = the 3D model, 2 = the 4D one)
ROWS = {
    "k1": ("dsnet-k1-track", 1),
    "k1-tta4": ("dsnet-k1-tta4", 1),
    "k2": ("dsnet-k2-stitch", 2),
    "k2-tta4": ("dsnet-k2-tta4", 2),
    "k1-ground": ("dsnet-k1-ground", 1),  # --match (docs/sensor_match.md)
    "k1-both": ("dsnet-k1-both", 1),
    "k2-ground": ("dsnet-k2-ground", 2),
    "k2-both": ("dsnet-k2-both", 2),
}
METRICS = ("miou", "pq", "pq_things", "pq_stuff", "lstq")
TOP = 3  # wrong classes listed per ground-truth class


def make_cell(root: Path, name: str) -> tuple[Path, list[str] | None]:
    """Generate cell ``name`` under ``root/name`` unless the same one is there; the log and the
    sequences to label (None: all of them)."""
    if name in REAL:
        return pandaset_cell(root, name), list(PANDASET_SEQUENCES)
    out = root / name
    stamp = out / "bench_cell.json"
    if name == OTHER:
        want = {"generator": "other", "sequences": VALIDATION_SEQUENCES, "frames": VALIDATION_FRAMES}
    else:
        seed, first, setups = CELLS[name]
        want = {"seed": seed, "first": first, "setups": setups, "frames": FRAMES}
    if stamp.exists() and json.loads(stamp.read_text()) == json.loads(json.dumps(want)):
        return out, None
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
    return out, None


def pandaset_cell(root: Path, name: str) -> Path:
    """The PandaSet log of cell ``name``: ``root/pandaset-002`` as ``unpack.py`` writes it
    (``pandaset``), or its validation sequences dequantised (``pandaset-dq``)."""
    from _stability import jitter_log

    log = root / "pandaset-002"
    stamp = log / "bench_cell.json"
    want = {
        "source": str(PANDASET_SOURCE / "pandaset-002.npz"),
        "bytes": (PANDASET_SOURCE / "pandaset-002.npz").stat().st_size,
    }
    if not (stamp.exists() and json.loads(stamp.read_text()) == want):
        res = subprocess.run(
            [sys.executable, str(PANDASET_SOURCE / "unpack.py"), str(log)], capture_output=True, text=True
        )
        if res.returncode != 0:
            raise SystemExit(f"{PANDASET_SOURCE / 'unpack.py'}: failed:\n{res.stderr[-2000:]}")
        stamp.write_text(json.dumps(want) + "\n")
    if name == PANDASET:
        return log
    return jitter_log(log, root / PANDASET_DQ, list(PANDASET_SEQUENCES), mm=5.0, seed=DQ_SEED)


def run_rows(
    out: Path, data: Path, ckpt: str | None, keys: list[str], refine: bool, seqs: list[str] | None = None
) -> dict:
    """``bench_methods.py`` rows ``keys`` on ``data`` (its ``seqs``; None: all) with DS-Net
    checkpoint ``ckpt`` (None: the bundled one of the row's k); their results."""
    methods = [ROWS[k][0] for k in keys]
    cmd = [sys.executable, str(BENCH / "bench_methods.py"), "--out", str(out), "--data", str(data)]
    cmd += ["--rows", ",".join(methods)]
    if ckpt:
        cmd += ["--checkpoint-dsnet", ckpt]
    if seqs:
        cmd += ["--sequences", ",".join(seqs)]
    cmd.append("--refine" if refine else "--no-refine")
    res = subprocess.run(cmd, capture_output=True, text=True)
    if res.returncode != 0:
        raise SystemExit(f"{out}: bench_methods failed:\n{res.stderr[-3000:]}")
    rows = json.loads((out / "bench_methods.json").read_text())["rows"]
    return {k: rows[ROWS[k][0]] for k in keys}


def score_before_refine(store: Path, data: Path, seqs: list[str] | None) -> dict | None:
    """bench_methods scores of the labels a refined row's store holds before ``refine`` (the stage
    refine reads); None when the row has no refine stage."""
    from bench_methods import Scores

    from dsnet_core.io.semantickitti import SemanticKittiReader
    from dsnet_core.labels import load_label_map
    from storage.run import RunStore
    from tasks.run_config import read_run

    rs = RunStore(store)
    pipeline = read_run(rs).pipeline()
    names = pipeline.names()
    if "refine" not in names:
        return None
    before = names[names.index("refine") - 1]
    reader = SemanticKittiReader(data)
    scores = Scores(load_label_map("semantic-kitti"))
    for seq in seqs or reader.sequences():
        labels = rs.arrays(seq, pipeline[before].contract)
        for ref in reader.frames(seq):
            scores.add(seq, ref.frame_id, reader.labels(ref), labels.read_item(ref.index)["label"])
    return scores.summary()


def stability(
    out: Path, data: Path, jittered: Path, seqs: list[str] | None, ckpt: str | None, key: str, ref_store: Path
) -> dict:
    """Row ``key`` up to ``infer`` on the jittered copy ``jittered`` of ``data`` (store ``out``), compared
    with the ``infer`` stage of the row's store ``ref_store`` (:func:`_stability.changed_share`)."""
    from _stability import changed_share

    from dsnet_core.io.semantickitti import SemanticKittiReader
    from dsnet_core.labels import load_label_map

    seqs = seqs or SemanticKittiReader(data).sequences()
    cmd = [sys.executable, str(BENCH / "_stability.py"), "--data", str(jittered), "--store", str(out)]
    cmd += ["--sequences", ",".join(seqs), "--row", ROWS[key][0]]
    if ckpt:
        cmd += ["--checkpoint", ckpt]
    res = subprocess.run(cmd, capture_output=True, text=True)
    if res.returncode != 0:
        raise SystemExit(f"{out}: the jittered infer failed:\n{res.stderr[-3000:]}")
    names = list(load_label_map("semantic-kitti").class_names)
    if ROWS[key][1] != 1:  # a k-scan volume's points are not one scan's: no cell analysis
        return changed_share(ref_store, out, seqs, names)
    from dsnet_core.checkpoints import bundled_checkpoint
    from dsnet_core.model.card import read_card

    grid = read_card(ckpt or bundled_checkpoint(1)).config.grid
    return changed_share(ref_store, out, seqs, names, logs=(data, jittered), grid=grid)


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


def _sequences(data: Path) -> list[str]:
    from dsnet_core.io.semantickitti import SemanticKittiReader

    return SemanticKittiReader(data).sequences()


def _fmt(x: float | None, digits: int = 3) -> str:
    return "–" if x is None else f"{x:.{digits}f}"


def _present(r: dict, before: bool = False) -> dict:
    """The present-class means of a row result (computed when the result predates them)."""
    key = "present_before_refine" if before else "present"
    if key in r:
        return r[key]
    return present_scores(r["scores_before_refine" if before else "scores"])


def _flip(r: dict) -> str:
    st = r.get("stability")
    return "–" if st is None else f"{100 * st['share']:.2f}"


def _score_table(results: dict, before: bool) -> list[str]:
    head = ["model", "cell", "row", "mIoU", "mIoU pres.", "PQ", "PQ pres.", "PQ^Th", "PQ^St", "LSTQ"]
    head += [] if before else ["flip %", "s/frame"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for model, cells in results.items():
        for cell, rows in cells.items():
            for key, r in rows.items():
                s = r["scores_before_refine" if before else "scores"]
                p = _present(r, before)
                row = [model, cell, key, _fmt(s["miou"]), _fmt(p["miou_present"]), _fmt(s["pq"])]
                row += [_fmt(p.get("pq_present")), _fmt(s["pq_things"]), _fmt(s["pq_stuff"]), _fmt(s["lstq"])]
                if not before:
                    row += [_flip(r), f"{sum(r['s_per_frame'].values()):.2f}"]
                lines.append("| " + " | ".join(row) + " |")
    return lines


def markdown(results: dict) -> str:
    """The tables of ``results`` (model → cell → row → bench_methods result, with ``present``,
    optionally ``stability`` and ``scores_before_refine``)."""
    any_scores = next(r["scores"] for c in results.values() for rs in c.values() for r in rs.values())
    names = [n for n in any_scores["class_names"][1:]]
    lines = [
        "## Scores (official mode)",
        "",
        "pres.: the mean over the classes with ground-truth points in the cell (the official means",
        f"count an absent class as 0); flip %: points whose predicted class changes under ±{JITTER_MM:g} mm",
        "jitter.",
        "",
        *_score_table(results, before=False),
    ]
    if any("scores_before_refine" in r for c in results.values() for rs in c.values() for r in rs.values()):
        lines += ["", "## Before refine (the same stores' labels before the refine stage)", ""]
        sub = {
            m: {c: {k: r for k, r in rs.items() if "scores_before_refine" in r} for c, rs in cells.items()}
            for m, cells in results.items()
        }
        lines += _score_table(sub, before=True)
    if any("stability" in r for c in results.values() for rs in c.values() for r in rs.values()):
        lines += [
            "",
            f"## Stability under ±{JITTER_MM:g} mm jitter",
            "",
            "The network's classes (infer stage). flip: share of points whose class changes; unsure:",
            f"share of the points whose top-two probability margin is below {LOW_MARGIN:g}, and of the",
            "flips; cell moved: share of points the jitter moves to another cylinder cell; kept: share",
            "of the flips whose point stayed in its cell (k = 1 only).",
            "",
        ]
        head = ["model", "cell", "row", "flip %", "unsure % (points)", "unsure % (flips)"]
        head += ["cell moved %", "kept % (flips)"]
        lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        for model, cells in results.items():
            for cell, rows in cells.items():
                for key, r in rows.items():
                    st = r.get("stability")
                    if st is None:
                        continue
                    vals = [
                        st.get(f)
                        for f in ("low_margin", "flips_low_margin", "cell_moved", "flips_in_kept_cells")
                    ]
                    row = [
                        model,
                        cell,
                        key,
                        _flip(r),
                        *("–" if v is None else f"{100 * v:.1f}" for v in vals),
                    ]
                    lines.append("| " + " | ".join(row) + " |")
    lines += ["", "## Mean over the held-out synthetic cells, the other generator and PandaSet", ""]
    head = ["model", "row", "synth mIoU", "synth PQ", "other mIoU", "other PQ", "other LSTQ"]
    head += ["PandaSet mIoU", "mIoU pres.", "PQ", "PQ pres.", "LSTQ", "flip %"]
    lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for model, cells in results.items():
        keys = list(next(iter(cells.values())))
        for key in keys:
            synth = [cells[c][key]["scores"] for c in cells if c in CELLS and key in cells[c]]
            other = cells.get(OTHER, {}).get(key, {}).get("scores")
            real = cells.get(PANDASET, {}).get(key)
            row = [model, key]
            row += [_fmt(float(np.mean([s[m] for s in synth]))) if synth else "–" for m in ("miou", "pq")]
            row += [_fmt(other[m]) if other else "–" for m in ("miou", "pq", "lstq")]
            if real:
                p = _present(real)
                s = real["scores"]
                row += [_fmt(s["miou"]), _fmt(p["miou_present"]), _fmt(s["pq"]), _fmt(p.get("pq_present"))]
                row += [_fmt(s["lstq"]), _flip(real)]
            else:
                row += ["–"] * 6
            lines.append("| " + " | ".join(row) + " |")
    for title, field in (("IoU", "class_iou"), ("PQ", "class_pq")):
        lines += ["", f"## {title} per class (– : absent from the cell's ground truth)", ""]
        head = ["model", "cell", "row", *names]
        lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        for model, cells in results.items():
            for cell, rows in cells.items():
                for key, r in rows.items():
                    score = r["scores"].get(field, {})
                    absent = set(_present(r)["absent"])
                    vals = [_fmt(None if c in absent else score.get(c), 2) for c in names]
                    lines.append("| " + " | ".join([model, cell, key, *vals]) + " |")
    row_keys = list(dict.fromkeys(k for c in results.values() for rs in c.values() for k in rs))
    for key in row_keys:
        lines += [
            "",
            f"## Top confusions ({key})",
            "",
            "The share of each ground-truth class's points labelled right (bold), then its most frequent",
            "wrong classes (% of the class's points).",
            "",
        ]
        for model, cells in results.items():
            mine = {cell: rows[key] for cell, rows in cells.items() if key in rows}
            lines += [
                f"**{model}**",
                "",
                "| ground truth | " + " | ".join(mine) + " |",
                "|---|" + "---|" * len(mine),
            ]
            tables = {
                cell: confusions(np.asarray(r["scores"]["confusion"]), r["scores"]["class_names"])
                for cell, r in mine.items()
            }
            for name in names:
                cols = []
                for cell in mine:
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
    ap.add_argument(
        "--refine",
        action="store_true",
        help="score the labels after refine, and before it (default: before only)",
    )
    ap.add_argument("--no-stability", action="store_true", help="leave out the ±5 mm jitter column")
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
    if any(c in REAL for c in cell_names) and not (PANDASET_SOURCE / "unpack.py").exists():
        print(f"{PANDASET_SOURCE} is absent: the PandaSet cells are left out", flush=True)
        cell_names = [c for c in cell_names if c not in REAL]
    sys.path.insert(0, str(REPO))
    from _stability import JITTER_SEED, jitter_log

    args.out.mkdir(parents=True, exist_ok=True)
    results: dict = {}
    for spec in args.model:
        name, _, paths = spec.partition("=")
        one, _, four = paths.partition(":")
        if name == "bundled" and not paths:  # what `dsnet label` takes without --checkpoint
            ckpts: dict[int, str | None] = {1: None, 2: None}
        else:
            ckpts = {1: str(Path(one).resolve()), 2: str(Path(four or one).resolve())}
        results[name] = {}
        for cell in cell_names:
            data, seqs = make_cell(args.out / "logs", cell)
            results[name][cell] = {}
            for k in (1, 2):
                mine = [key for key in keys if ROWS[key][1] == k]
                if not mine:
                    continue
                where = args.out / name / cell / f"k{k}"
                results[name][cell].update(run_rows(where, data, ckpts[k], mine, args.refine, seqs))
                for key in mine:
                    r = results[name][cell][key]
                    store = where / ROWS[key][0]
                    r["present"] = present_scores(r["scores"])
                    if args.refine and (before := score_before_refine(store, data, seqs)) is not None:
                        r["scores_before_refine"] = before
                        r["present_before_refine"] = present_scores(before)
                    if not args.no_stability:
                        jittered = jitter_log(
                            data,
                            args.out / "logs" / f"{cell}-jitter",
                            seqs or _sequences(data),
                            JITTER_MM,
                            JITTER_SEED,
                        )
                        r["stability"] = stability(
                            where / "jitter" / ROWS[key][0], data, jittered, seqs, ckpts[k], key, store
                        )
            for key in keys:
                r = results[name][cell][key]
                s, pr = r["scores"], r["present"]
                flip = f" flip {100 * r['stability']['share']:.2f} %" if "stability" in r else ""
                print(
                    f"{name} {cell} {key}: mIoU {s['miou']:.3f} (present {pr['miou_present']:.3f}) "
                    f"PQ {s['pq']:.3f} (present {pr['pq_present']:.3f}) LSTQ {s['lstq']:.3f}{flip}",
                    flush=True,
                )
            (args.out / "transfer.json").write_text(json.dumps(results, indent=2) + "\n")
    md = markdown(results)
    (args.out / "transfer.md").write_text(md)
    print()
    print(md)


if __name__ == "__main__":
    main()
