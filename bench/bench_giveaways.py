"""Give-aways of ``dsnet synth``: what separates the classes a model confuses off the generator.

For the confused pairs of issue #32 (building/fence, trunk/person, sidewalk/terrain, road/terrain,
car/other-vehicle) this measures, from the ground truth of generated logs only, the cues a network
could learn to tell the two apart:

- objects (building, fence, trunk, person, car, other-vehicle, vegetation): segments (instances for
  things; 0.5 m-connected components of a class's points for stuff) and their top and base height
  above the local ground, vertical extent, horizontal length and thickness (5–95 % spread along and
  across the main horizontal axis), facade texture (median RMS distance of the points from the best
  plane of each 3 m piece), points, median range, median remission, the ground class they stand on,
  and (trunk, person) whether vegetation hangs within 2 m above them;
- ground (road, sidewalk, terrain, parking): 1 m cells and their height above the road nearby (the
  kerb step), roughness (std of heights in the cell), remission, range.

Each feature gets, per pair, both classes' median [10th–90th percentile] and a separability: the
probability that a random segment (cell) of one class has the larger value than one of the other,
folded to [0.5, 1] (0.5: the feature says nothing; 1.0: a threshold separates the classes). A cue
near 1.0 that the world lacks (public SemanticKITTI facts, see ``docs/synth_giveaways.md``) is a
give-away to widen.

Run: ``OMP_NUM_THREADS=1 .venv/bin/python bench/bench_giveaways.py --out DIR [--variety base|wide]
[--styles residential,arterial,downtown,country] [--sensor hdl64] [--sequences 8] [--frames 3]``;
writes ``DIR/giveaways.json`` and ``DIR/giveaways.md``. The logs are generated under ``DIR/log``.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree
from scipy.stats import rankdata

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

NAMES = {10: "car", 20: "other-vehicle", 13: "other-vehicle", 30: "person", 40: "road", 44: "parking",
         48: "sidewalk", 49: "other-ground", 50: "building", 51: "fence", 70: "vegetation", 71: "trunk",
         72: "terrain", 60: "road"}  # fmt: skip
MOVING = {252: 10, 253: 31, 254: 30, 255: 32, 256: 16, 257: 13, 258: 18, 259: 20}
GROUND = (40, 44, 48, 49, 60, 72)
OBJECTS = ("building", "fence", "trunk", "person", "car", "other-vehicle", "vegetation")
THINGS = ("car", "other-vehicle", "person")
PAIRS = (
    ("building", "fence"),
    ("trunk", "person"),
    ("sidewalk", "terrain"),
    ("road", "terrain"),
    ("car", "other-vehicle"),
)
OBJECT_FEATURES = ("top", "base", "vertical", "length", "thickness", "texture", "points", "range",
                   "remission", "on_terrain", "on_sidewalk", "canopy")  # fmt: skip
CELL_FEATURES = ("step", "roughness", "remission", "range")


def ground_model(xyz: np.ndarray, sem: np.ndarray) -> tuple[cKDTree, np.ndarray, np.ndarray]:
    """1 m cells of ground points: a tree over their centres, their low height (20th percentile,
    metres) and their majority raw class."""
    g = np.isin(sem, GROUND)
    cell = np.floor(xyz[g, :2]).astype(np.int64)
    keys, inv = np.unique(cell, axis=0, return_inverse=True)
    inv = inv.ravel()
    order = np.lexsort((xyz[g, 2], inv))
    starts = np.searchsorted(inv[order], np.arange(len(keys)))
    counts = np.bincount(inv, minlength=len(keys))
    low = xyz[g, 2][order][starts + (0.2 * (counts - 1)).astype(np.int64)]
    combo, votes = np.unique(inv * 256 + sem[g], return_counts=True)
    order = np.lexsort((votes, combo // 256))  # per cell, its most frequent class last
    cell_of = combo[order] // 256
    last = np.r_[cell_of[1:] != cell_of[:-1], True]
    cls = np.zeros(len(keys), np.int64)
    cls[cell_of[last]] = combo[order][last] % 256
    return cKDTree(keys + 0.5), low, cls


def components(xyz: np.ndarray, radius: float = 0.5) -> np.ndarray:
    """Connected components of points closer than ``radius`` (metres): ``(N,)`` component ids."""
    pairs = cKDTree(xyz).query_pairs(radius, output_type="ndarray")
    n = len(xyz)
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    return connected_components(graph, directed=False)[1]


def texture(xy: np.ndarray, xyz: np.ndarray, axis: np.ndarray) -> float:
    """Median RMS distance (metres) of the points of each 3 m piece along ``axis`` from its best plane."""
    along = xy @ axis
    out = []
    for k in np.unique(np.floor(along / 3.0)):
        p = xyz[np.floor(along / 3.0) == k]
        if len(p) >= 10:
            out.append(float(np.sqrt(np.linalg.eigvalsh(np.cov(p.T))[0])))
    return float(np.median(out)) if out else float("nan")


def object_rows(xyz, rem, sem, inst, ground) -> list[dict]:
    """One row of :data:`OBJECT_FEATURES` per segment of the :data:`OBJECTS` classes in one scan."""
    tree, low, gcls = ground
    names = np.array([NAMES.get(int(s), "") for s in sem])
    _, near = tree.query(xyz[:, :2])
    height = xyz[:, 2] - low[near]
    veg = xyz[names == "vegetation"]
    veg_tree = cKDTree(veg[:, :2]) if len(veg) else None
    rows = []
    for name in OBJECTS:
        m = np.flatnonzero(names == name)
        if len(m) < 10:
            continue
        seg = inst[m] if name in THINGS else components(xyz[m])
        for s in np.unique(seg):
            idx = m[seg == s]
            if len(idx) < 10:
                continue
            p, h = xyz[idx], height[idx]
            xy = p[:, :2] - p[:, :2].mean(axis=0)
            v = np.linalg.eigh(np.cov(xy.T))[1] if len(idx) > 2 else np.eye(2)
            major, minor = v[:, 1], v[:, 0]
            spread = [float(np.percentile(xy @ a, 95) - np.percentile(xy @ a, 5)) for a in (major, minor)]
            under = gcls[near[idx]]
            row = {
                "class": name,
                "top": float(np.percentile(h, 98)),
                "base": float(np.percentile(h, 2)),
                "length": spread[0],
                "thickness": spread[1],
                "points": float(len(idx)),
                "range": float(np.median(np.linalg.norm(p, axis=1))),
                "remission": float(np.median(rem[idx])),
                "texture": texture(xy, p, major),
                "on_terrain": float(np.mean(under == 72)),
                "on_sidewalk": float(np.mean(under == 48)),
                "canopy": float("nan"),
            }
            row["vertical"] = row["top"] - row["base"]
            if name in ("trunk", "person"):
                c = p.mean(axis=0)
                row["canopy"] = 0.0
                if veg_tree is not None:
                    k = veg_tree.query_ball_point(c[:2], 1.5)
                    row["canopy"] = float(any(0.0 < veg[j, 2] - p[:, 2].max() < 2.0 for j in k))
            rows.append(row)
    return rows


def cell_rows(xyz, rem, sem, ground) -> list[dict]:
    """One row of :data:`CELL_FEATURES` per 1 m cell of road, sidewalk, terrain or parking points."""
    rows = []
    road = xyz[np.isin(sem, (40, 60))]
    road_tree = cKDTree(road[:, :2]) if len(road) else None
    for raw in (40, 44, 48, 72):
        m = sem == raw
        if m.sum() < 5:
            continue
        cell = np.floor(xyz[m, :2]).astype(np.int64)
        inv = np.unique(cell, axis=0, return_inverse=True)[1].ravel()
        for k in np.flatnonzero(np.bincount(inv) >= 4):
            p, r = xyz[m][inv == k], rem[m][inv == k]
            row = {"class": NAMES[raw], "roughness": float(np.std(p[:, 2])), "remission": float(np.median(r)),
                   "range": float(np.median(np.linalg.norm(p, axis=1))), "step": float("nan")}  # fmt: skip
            if road_tree is not None and raw != 40:
                near = road_tree.query_ball_point(p[:, :2].mean(axis=0), 4.0)
                if len(near) >= 4:
                    row["step"] = float(np.median(p[:, 2]) - np.median(road[near, 2]))
            rows.append(row)
    return rows


def separability(a: np.ndarray, b: np.ndarray) -> float:
    """P(a > b) + P(a = b)/2 folded to [0.5, 1]; NaN when either side is empty."""
    a, b = a[np.isfinite(a)], b[np.isfinite(b)]
    if not len(a) or not len(b):
        return float("nan")
    ranks = rankdata(np.concatenate([a, b]))
    auc = (ranks[: len(a)].sum() - len(a) * (len(a) + 1) / 2) / (len(a) * len(b))
    return float(max(auc, 1 - auc))


def summary(values: np.ndarray) -> str:
    v = values[np.isfinite(values)]
    if not len(v):
        return "–"
    p10, p50, p90 = np.percentile(v, [10, 50, 90])
    return f"{p50:.2f} [{p10:.2f}–{p90:.2f}]"


def analyse(log: Path, every: int = 1) -> tuple[list[dict], list[dict]]:
    """Object and cell rows of every ``every``-th frame of the log at ``log``."""
    from dsnet_core.io.semantickitti import SemanticKittiReader

    reader = SemanticKittiReader(log)
    objects, cells = [], []
    for seq in reader.sequences():
        for ref in reader.frames(seq)[::every]:
            scan, label = reader.scan(ref), reader.labels(ref)
            sem = (label & 0xFFFF).astype(np.int64)
            for m, c in MOVING.items():
                sem[sem == m] = c
            inst = (label >> 16).astype(np.int64)
            xyz, rem = scan[:, :3].astype(np.float64), scan[:, 3].astype(np.float64)
            ground = ground_model(xyz, sem)
            objects += object_rows(xyz, rem, sem, inst, ground)
            cells += cell_rows(xyz, rem, sem, ground)
    return objects, cells


def tables(objects: list[dict], cells: list[dict]) -> tuple[dict, str]:
    """Per pair and feature: both summaries and the separability; the JSON and the markdown."""
    out, lines = {}, []
    for a, b in PAIRS:
        rows, feats = (cells, CELL_FEATURES) if a in ("road", "sidewalk") else (objects, OBJECT_FEATURES)
        va = {f: np.array([r[f] for r in rows if r["class"] == a], float) for f in feats}
        vb = {f: np.array([r[f] for r in rows if r["class"] == b], float) for f in feats}
        n_a, n_b = len(va[feats[0]]), len(vb[feats[0]])
        lines += [
            f"### {a} ({n_a}) / {b} ({n_b})",
            "",
            f"| feature | {a} | {b} | separability |",
            "|---|---|---|---|",
        ]
        out[f"{a}/{b}"] = {}
        for f in feats:
            sep = separability(va[f], vb[f])
            out[f"{a}/{b}"][f] = {"a": summary(va[f]), "b": summary(vb[f]), "separability": sep}
            mark = f"**{sep:.2f}**" if sep >= 0.9 else f"{sep:.2f}"
            lines.append(f"| {f} | {summary(va[f])} | {summary(vb[f])} | {mark} |")
        lines.append("")
    return out, "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=None, help="output folder (default: a new temporary folder)")
    ap.add_argument("--styles", default="residential,arterial,downtown,country")
    ap.add_argument("--sensor", default="hdl64")
    ap.add_argument("--variety", default="base", help="the generator's variety (base | wide)")
    ap.add_argument("--sequences", type=int, default=8, help="per style")
    ap.add_argument("--frames", type=int, default=3)
    ap.add_argument("--seed", type=int, default=707)
    args = ap.parse_args()
    args.out = args.out or Path(tempfile.mkdtemp(prefix="bench-giveaways-"))
    from dsnet_core.synth import SynthConfig, generate_log

    log = args.out / f"log-{args.variety}"
    stamp = log / "bench_log.json"
    want = {k: getattr(args, k) for k in ("styles", "sensor", "variety", "sequences", "frames", "seed")}
    if not stamp.exists() or json.loads(stamp.read_text()) != want:
        config = SynthConfig(variety=args.variety) if args.variety != "base" else None
        for i, style in enumerate(args.styles.split(",")):
            generate_log(
                log,
                sequences=args.sequences,
                frames=args.frames,
                seed=args.seed,
                sensor=args.sensor,
                style=style,
                first_sequence=i * args.sequences,
                overwrite=True,
                config=config,
            )
        stamp.write_text(json.dumps(want) + "\n")
    objects, cells = analyse(log)
    result, md = tables(objects, cells)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / f"giveaways-{args.variety}.json").write_text(
        json.dumps({"setup": want, "pairs": result}, indent=1)
    )
    head = f"# dsnet synth give-aways ({args.variety}; {args.styles}; {args.sensor})\n\n"
    (args.out / f"giveaways-{args.variety}.md").write_text(head + md)
    print(head + md)


if __name__ == "__main__":
    main()
