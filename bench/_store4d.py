"""Reading a finished 4D label run back for benchmarks: stitched labels, fused volumes, splits.

Plain functions over a :class:`storage.run.RunStore` whose stages ran through ``stitch``; they
assume a clean log (no quarantined frames), so a volume's frame numbers are the ingest indices.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from dsnet_core.labels import LabelMap
from dsnet_core.temporal.stitching import VolumeLabels
from storage.run import RunStore
from tasks.methods import get_pipeline

P = get_pipeline()  # the DS-Net stages


def stitched(store: RunStore, seq: str) -> list[np.ndarray]:
    """The stitched final labels ``(N_f,) uint32`` of every frame of ``seq`` in ingest order."""
    from flows.export import final_labels

    out = []
    for _, frame_id, label in final_labels(store, [seq]):
        if label is None:
            raise SystemExit(f"{seq}/{frame_id} has no final label (quarantined): score on a clean log")
        out.append(label)
    return out


def poses(store: RunStore, seq: str) -> np.ndarray:
    """``(F, 4, 4)`` LiDAR-frame poses the pipeline used (ingest's frame table)."""
    t = store.read_table(seq, P["ingest"].table("frames")).to_pydict()
    return np.asarray(t["pose"], np.float64).reshape(-1, 4, 4)


def volumes(store: RunStore, seq: str) -> list[VolumeLabels]:
    """Every volume's panoptic output (``fuse``: train ids, volume-local raw ids) with its points'
    source frames and indices (``align``), as the stitcher takes them."""
    t = store.read_table(seq, P["ingest"].table("frames")).to_pydict()
    sizes = np.asarray(t["n_points"], np.int64)
    windows = store.read_manifest(seq, "align").plan["windows"]
    align, fuse = store.arrays(seq, P["align"].contract), store.arrays(seq, P["fuse"].contract)
    out = []
    for v, w in enumerate(windows):
        src = align.read_item(v, ["source_frame", "source_index"])
        fused = fuse.read_item(v, ["sem", "inst"])
        out.append(
            VolumeLabels(
                frames=np.asarray(w, np.int64),
                source_frame=src["source_frame"].astype(np.int64),
                source_index=src["source_index"].astype(np.int64),
                semantic=fused["sem"].astype(np.int64),
                instance=fused["inst"].astype(np.int64),
                frame_sizes=sizes[np.asarray(w, np.int64)],
            )
        )
    return out


@dataclass
class SplitStats:
    """Ground-truth objects inside volumes and how often the model cut them into pieces.

    An object (one ground-truth thing instance with ≥ ``min_points`` points in a volume) is
    *moving* when its centroid, in the volume's reference frame, moves ≥ ``min_speed`` metres per
    frame between the first and the last scan it appears in (needs two scans: k ≥ 2); it is
    *split* when at least two predicted instances hold ≥ 10 % of its points each, and *split by
    scan* when moreover each of those pieces takes ≥ 80 % of its points from a single scan (the
    signature of offsets that point to each scan's own centre instead of a volume-wide one).
    """

    objects: dict[str, int] = field(default_factory=lambda: {"moving": 0, "static": 0})
    split: dict[str, int] = field(default_factory=lambda: {"moving": 0, "static": 0})
    split_by_scan: dict[str, int] = field(default_factory=lambda: {"moving": 0, "static": 0})

    def rates(self) -> dict[str, dict[str, float | int]]:
        return {
            kind: {
                "objects": self.objects[kind],
                "split": self.split[kind] / self.objects[kind] if self.objects[kind] else float("nan"),
                "split_by_scan": self.split_by_scan[kind] / self.objects[kind]
                if self.objects[kind]
                else float("nan"),
            }
            for kind in ("moving", "static")
        }


def volume_splits(
    store: RunStore,
    seq: str,
    label_map: LabelMap,
    stats: SplitStats,
    min_points: int = 50,
    min_speed: float = 0.5,
) -> SplitStats:
    """Add ``seq``'s volumes to ``stats`` (needs the ground truth that ``align`` carries)."""
    align, fuse = store.arrays(seq, P["align"].contract), store.arrays(seq, P["fuse"].contract)
    thing_lut = label_map.is_thing()
    for v in range(align.n_items):
        a = align.read_item(v, ["points", "source_frame", "labels"])
        inst = fuse.read_item(v, ["inst"])["inst"].astype(np.int64)
        gt = a["labels"].astype(np.int64)
        sel = thing_lut[label_map.to_train(gt & 0xFFFF)] & ((gt >> 16) > 0)
        for key in np.unique(gt[sel]).tolist():
            m = gt == key
            if m.sum() < min_points:
                continue
            src, xyz, pred = a["source_frame"][m], a["points"][m, :3].astype(np.float64), inst[m]
            frames = np.unique(src)
            moving = False
            if frames.size >= 2:
                c0, c1 = xyz[src == frames[0]].mean(0), xyz[src == frames[-1]].mean(0)
                moving = np.linalg.norm(c1 - c0) / (frames[-1] - frames[0]) >= min_speed
            kind = "moving" if moving else "static"
            stats.objects[kind] += 1
            ids, n = np.unique(pred[pred > 0], return_counts=True)
            pieces = ids[n >= 0.1 * m.sum()]
            if pieces.size < 2:
                continue
            stats.split[kind] += 1
            by_scan = all(
                np.bincount(src[pred == p] - frames[0]).max() >= 0.8 * (pred == p).sum() for p in pieces
            )
            stats.split_by_scan[kind] += int(by_scan and frames.size >= 2)
    return stats
