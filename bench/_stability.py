"""Label stability under coordinate noise: how many points change their predicted class when every
coordinate of a log moves by uniform ±``mm`` millimetres (seeded), the model unchanged.

:func:`jitter_log` writes the moved copy of a SemanticKITTI-layout log (remission, labels, poses,
calib and times as they are); :func:`infer_only` runs the row's pipeline on it only as far as the
``infer`` stage (the network's per-point class, before shifting, fusion, tracking and refine vote
on it), in a store of its own; :func:`changed_share` compares those classes, item by item (a scan,
or a k-scan volume at k > 1), with the ``infer`` stage of the row's store on the unmoved log.

Where the flips come from: the share of flipped points whose unmoved prediction had a top-two
probability margin below ``LOW_MARGIN``, and, for single scans (k = 1, where an item's points are
the scan's, in order), the share of points whose cylinder cell the jitter changed and the share of
the flips whose point stayed in its cell (a voxel whose prediction changed although its points did
not leave it: the network's input moved, not the quantisation).

Run as a worker by ``bench_transfer.py``: ``python bench/_stability.py --data LOG --store DIR
--sequences 31,32 --row dsnet-k1-track [--checkpoint CKPT]`` runs ingest → align → infer.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

import numpy as np

BENCH = Path(__file__).resolve().parent
JITTER_MM = 5.0
JITTER_SEED = 5
LOW_MARGIN = 0.1  # top-1 minus top-2 probability below which a prediction counts as unsure


def jitter_points(scan: np.ndarray, mm: float, rng: np.random.Generator) -> np.ndarray:
    """``scan`` (float32 ``(N, 4)``: x, y, z, remission) with x, y, z each moved by uniform
    ``[-mm, mm]`` millimetres drawn from ``rng``; remission unchanged. float32 ``(N, 4)``."""
    out = np.array(scan, dtype=np.float32, copy=True)
    step = rng.uniform(-mm / 1000.0, mm / 1000.0, size=(len(out), 3))
    out[:, :3] = (out[:, :3].astype(np.float64) + step).astype(np.float32)
    return out


def jitter_log(
    src: Path, dst: Path, sequences: list[str], mm: float = JITTER_MM, seed: int = JITTER_SEED
) -> Path:
    """Write ``sequences`` of the log at ``src`` with jittered coordinates to ``dst`` (skipped when the
    same copy is there). Frame ``i`` of sequence ``s`` draws from ``default_rng([seed, int(s), i])``,
    so a copy does not depend on which other sequences or frames it holds."""
    from dsnet_core.io import kitti
    from dsnet_core.io.semantickitti import SemanticKittiReader

    stamp = dst / "jittered.json"
    want = {"source": str(Path(src).resolve()), "sequences": list(sequences), "mm": mm, "seed": seed}
    if stamp.exists() and json.loads(stamp.read_text()) == want:
        return dst
    reader = SemanticKittiReader(src)
    for seq in sequences:
        out = dst / "sequences" / seq
        shutil.rmtree(out, ignore_errors=True)
        shutil.copytree(reader.seq_dir(seq), out, ignore=shutil.ignore_patterns("velodyne"))
        (out / "velodyne").mkdir()
        for i, ref in enumerate(reader.frames(seq)):
            rng = np.random.default_rng([seed, int(seq), i])
            kitti.write_scan(out / "velodyne" / ref.scan_path.name, jitter_points(reader.scan(ref), mm, rng))
    stamp.write_text(json.dumps(want) + "\n")
    return dst


def flip_counts(ref: np.ndarray, new: np.ndarray, n_classes: int) -> tuple[np.ndarray, np.ndarray]:
    """Points per reference class and how many of them changed class.

    Args:
        ref: ``(N,)`` integer predicted class per point on the unmoved input.
        new: ``(N,)`` the same points' predicted class on the moved input.
        n_classes: classes (ids ``0..n_classes-1``).

    Returns:
        ``(points, changed)``, int64 ``(n_classes,)`` each, indexed by the reference class.

    Raises:
        ValueError: the two predictions cover different numbers of points.
    """
    ref, new = np.asarray(ref).ravel(), np.asarray(new).ravel()
    if ref.shape != new.shape:
        raise ValueError(f"predictions of {ref.size} and {new.size} points cannot be compared point by point")
    points = np.bincount(ref, minlength=n_classes)[:n_classes].astype(np.int64)
    changed = np.bincount(ref[ref != new], minlength=n_classes)[:n_classes].astype(np.int64)
    return points, changed


def top_margin(probs: np.ndarray) -> np.ndarray:
    """float32 ``(N,)`` top-1 minus top-2 probability of ``(N, C)`` probabilities (uint8: ``q / 255``)."""
    p = np.asarray(probs, np.float32)
    if np.asarray(probs).dtype == np.uint8:
        p = p / 255.0
    top2 = np.partition(p, p.shape[1] - 2, axis=1)[:, -2:]
    return (top2[:, 1] - top2[:, 0]).astype(np.float32)


def cell_moved(ref_scan: np.ndarray, new_scan: np.ndarray, grid) -> np.ndarray:
    """bool ``(N,)``: the point's cylinder cell (:func:`~dsnet_core.model.cylinder.cylinder_features`,
    the model's own) differs between two ``(N, 4)`` scans of the same points."""
    import torch

    from dsnet_core.model.cylinder import cylinder_features

    a = cylinder_features(torch.from_numpy(np.ascontiguousarray(ref_scan, np.float32)), grid)[0]
    b = cylinder_features(torch.from_numpy(np.ascontiguousarray(new_scan, np.float32)), grid)[0]
    return (a != b).any(dim=1).numpy()


def changed_share(
    ref_store: Path,
    new_store: Path,
    sequences: list[str],
    names: list[str],
    logs: tuple[Path, Path] | None = None,
    grid=None,
) -> dict:
    """The share of points whose ``infer`` class differs between two stores of the same log's points.

    Args:
        logs: the unmoved and the moved log, with ``grid`` the model's cylinder grid: also measure
            which points changed cell (single-scan rows only: item ``i`` is frame ``i``).

    Returns:
        ``{"points": N, "changed": n, "share": n / N, "by_class": {name: share}, "low_margin": share
        of points with margin < LOW_MARGIN, "flips_low_margin": share of the changed points with it}``,
        ``by_class`` by the class predicted on the unmoved log (classes it predicts at all); with
        ``logs``, also ``"cell_moved"`` (share of points whose cell changed) and
        ``"flips_in_kept_cells"`` (share of the changed points that stayed in their cell).
    """
    from storage.run import RunStore
    from tasks.run_config import read_run

    points = np.zeros(len(names), np.int64)
    changed = np.zeros(len(names), np.int64)
    low = low_flips = moved = kept_flips = 0
    readers = None
    if logs is not None:
        from dsnet_core.io.semantickitti import SemanticKittiReader

        readers = [SemanticKittiReader(logs[0]), SemanticKittiReader(logs[1])]
    stores = [RunStore(ref_store), RunStore(new_store)]
    arrays = []
    for rs in stores:
        contract = read_run(rs).pipeline()["infer"].contract
        arrays.append({seq: rs.arrays(seq, contract) for seq in sequences})
    for seq in sequences:
        a, b = arrays[0][seq], arrays[1][seq]
        if a.n_items != b.n_items:
            raise ValueError(
                f"{new_store}: sequence {seq} has {b.n_items} infer items, {ref_store} {a.n_items}"
            )
        frames = [r.frames(seq) for r in readers] if readers else None
        for i in range(a.n_items):
            ref = a.read_item(i, ["sem", "probs"])
            new = b.read_item(i, ["sem"])["sem"]
            p, c = flip_counts(ref["sem"], new, len(names))
            points += p
            changed += c
            flip = ref["sem"] != new
            unsure = top_margin(ref["probs"]) < LOW_MARGIN
            low += int(unsure.sum())
            low_flips += int((flip & unsure).sum())
            if frames is not None:
                scans = [readers[j].scan(frames[j][i]) for j in range(2)]
                if len(scans[0]) != len(flip):
                    raise ValueError(f"{ref_store}: infer item {i} of {seq} is not frame {i} (k > 1?)")
                m = cell_moved(scans[0], scans[1], grid)
                moved += int(m.sum())
                kept_flips += int((flip & ~m).sum())
    total, n_changed = int(points.sum()), int(changed.sum())
    out = {
        "points": total,
        "changed": n_changed,
        "share": float(n_changed / total) if total else float("nan"),
        "by_class": {names[k]: float(changed[k] / points[k]) for k in range(len(names)) if points[k]},
        "low_margin": float(low / total) if total else float("nan"),
        "flips_low_margin": float(low_flips / n_changed) if n_changed else float("nan"),
    }
    if logs is not None:
        out["cell_moved"] = float(moved / total) if total else float("nan")
        out["flips_in_kept_cells"] = float(kept_flips / n_changed) if n_changed else float("nan")
    return out


def infer_only(data: Path, store: Path, sequences: list[str], row: str, checkpoint: str | None) -> None:
    """Run ``row``'s pipeline (a ``bench_methods.py`` row) on ``data`` up to and including ``infer``."""
    import torch

    sys.path.insert(0, str(BENCH))
    from bench_methods import ROWS, request_of

    from storage.run import RunStore
    from tests.helpers.plain_runner import run_stage_plain

    torch.set_num_threads(1)
    request = request_of(ROWS[row], data, store, sequences, {"dsnet": checkpoint}, refine=False)
    pipeline = request.pipeline()
    run = {
        **pipeline.record(),
        "data": str(data),
        "format": "auto",
        "sequences": sequences,
        "stages": request.stage_configs(pipeline),
        "options": {"block_size": 25},
    }
    rs = RunStore(store)
    rs.write_run_config("bench", run)
    names = pipeline.names()
    for seq in sequences:
        for stage in names[: names.index("infer") + 1]:
            run_stage_plain(rs, pipeline, seq, stage, run, "bench")


def main() -> None:
    ap = argparse.ArgumentParser(description="run a bench_methods row's pipeline up to infer")
    ap.add_argument("--data", type=Path, required=True)
    ap.add_argument("--store", type=Path, required=True)
    ap.add_argument("--sequences", required=True)
    ap.add_argument("--row", required=True)
    ap.add_argument("--checkpoint", default=None)
    args = ap.parse_args()
    sys.path.insert(0, str(BENCH.parent))
    infer_only(args.data, args.store, args.sequences.split(","), args.row, args.checkpoint)


if __name__ == "__main__":
    main()
