"""Oracle 4D labelling for tests and benchmarks: ground-truth semantics and noisy ground-truth
centres stand in for the network; everything after it is the real path — ``align`` volumes,
a clusterer, fusion, then stitching (4D) or the tracking baseline (k = 1).

With perfect semantics and centres that only carry regression noise, the stitched ids should
give LSTQ close to 1; and 4D volumes can be compared with single-scan clustering + tracking on
equal terms (same noise model, same clusterer).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from dsnet_core.instance.clustering import BFSConfig, Clusterer, get_clusterer
from dsnet_core.instance.fusion import fuse
from dsnet_core.labels import LabelMap
from dsnet_core.oracle.inputs import box_centres, noisy_centres
from dsnet_core.temporal.align import build_volume, plan_windows
from dsnet_core.temporal.stitching import Stitcher, VolumeLabels
from dsnet_core.temporal.tracking import Tracker


def _objects(semantic: np.ndarray, instance: np.ndarray, thing: np.ndarray) -> np.ndarray:
    """Compact object keys ``(N,) int64`` (> 0 on thing points with an id), class-distinct."""
    key = semantic.astype(np.int64) * (1 << 32) + instance.astype(np.int64)
    key = np.where(thing & (instance > 0), key, 0)
    _, inv = np.unique(key, return_inverse=True)
    return np.where(key > 0, inv + (0 if (key == 0).any() else 1), 0)


def _panoptic(
    xyz: np.ndarray,
    semantic: np.ndarray,
    instance: np.ndarray,
    label_map: LabelMap,
    clusterer: Clusterer,
    seed: int,
    noise_scale: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Oracle instance stage of one scan/volume (sensor at the origin): noisy gt centres →
    cluster → fuse. Returns (semantic, instance) ``(N,) int64``."""
    thing = label_map.is_thing()[semantic]
    obj = _objects(semantic, instance, thing)
    pts = xyz[thing].astype(np.float32)
    centres = noisy_centres(pts, box_centres(pts, obj[thing]), obj[thing], seed, scale=noise_scale)
    ids = np.zeros(semantic.size, np.int64)
    ids[thing] = clusterer.cluster(pts, centres, None)
    fused = fuse(xyz.astype(np.float32), semantic, ids, label_map.things)
    return fused.semantic, fused.instance


def _train(labels: np.ndarray, label_map: LabelMap) -> tuple[np.ndarray, np.ndarray]:
    labels = np.asarray(labels, dtype=np.uint32)
    return label_map.to_train(labels & 0xFFFF).astype(np.int64), (labels >> 16).astype(np.int64)


def oracle_volumes(
    scans: Sequence[np.ndarray],
    labels: Sequence[np.ndarray],
    poses: np.ndarray,
    label_map: LabelMap,
    k: int,
    stride: int | None = None,
    clusterer: Clusterer | None = None,
    seed: int = 0,
    noise_scale: float = 1.0,
) -> list[VolumeLabels]:
    """The fused k-scan volumes of a sequence: align → noisy volume-wide centres → cluster → fuse.

    Args:
        scans: per frame float32 ``(N_f, 4)`` sensor-frame points.
        labels: per frame uint32 ``(N_f,)`` ground truth (raw semantic | instance << 16).
        poses: ``(F, 4, 4)`` LiDAR-frame poses.
        k: scans per volume; stride: step between volumes (default ``k - 1``, one shared frame;
            k = 1 gives independent frames).
        clusterer: default BFS (radius 0.3 m) on the regressed centres.
        seed: noise seed; noise_scale: multiplies :data:`dsnet_core.oracle.NOISE_DEFAULTS`.
    """
    clusterer = clusterer or get_clusterer(BFSConfig())
    out = []
    for v, window in enumerate(plan_windows(len(scans), k, stride or max(k - 1, 1))):
        frames = list(window)
        vol = build_volume([scans[f] for f in frames], [poses[f] for f in frames], frames)
        sem_inst = [_train(labels[f], label_map) for f in frames]
        sem = np.concatenate([s for s, _ in sem_inst])
        inst = np.concatenate([i for _, i in sem_inst])
        fsem, finst = _panoptic(vol.points[:, :3], sem, inst, label_map, clusterer, seed + v, noise_scale)
        out.append(VolumeLabels(np.asarray(frames), vol.source_frame, vol.source_index, fsem, finst))
    return out


def stitch_sequence(volumes: Sequence[VolumeLabels], label_map: LabelMap) -> list[np.ndarray]:
    """Stitch a sequence's volumes; per-frame uint32 labels in frame order."""
    stitcher = Stitcher(label_map)
    out = {ff.frame: ff.label for v in volumes for ff in stitcher.add_volume(v)}
    return [out[f] for f in sorted(out)]


def oracle_4d(
    scans: Sequence[np.ndarray],
    labels: Sequence[np.ndarray],
    poses: np.ndarray,
    label_map: LabelMap,
    k: int,
    **kwargs,
) -> list[np.ndarray]:
    """:func:`oracle_volumes` then :func:`stitch_sequence`: per-frame uint32 labels with
    sequence-wide ids."""
    return stitch_sequence(oracle_volumes(scans, labels, poses, label_map, k, **kwargs), label_map)


def track_sequence(
    volumes: Sequence[VolumeLabels],
    scans: Sequence[np.ndarray],
    poses: np.ndarray,
    label_map: LabelMap,
    **tracker_kwargs,
) -> list[np.ndarray]:
    """Link single-scan (k = 1) volumes with :class:`Tracker`; per-frame uint32 labels."""
    tracker = Tracker(label_map, **tracker_kwargs)
    out = []
    for v in volumes:
        (f,) = v.frames.tolist()
        sem = np.empty_like(v.semantic)
        inst = np.empty_like(v.instance)
        sem[v.source_index], inst[v.source_index] = v.semantic, v.instance
        out.append(tracker.add_frame(scans[f][:, :3], sem, inst, poses[f]))
    return out


def oracle_tracking(
    scans: Sequence[np.ndarray],
    labels: Sequence[np.ndarray],
    poses: np.ndarray,
    label_map: LabelMap,
    clusterer: Clusterer | None = None,
    seed: int = 0,
    noise_scale: float = 1.0,
    **tracker_kwargs,
) -> list[np.ndarray]:
    """The baseline: per scan noisy centres → cluster → fuse (:func:`oracle_volumes` with k = 1)
    → :func:`track_sequence` (ego-motion compensated, constant velocity)."""
    vols = oracle_volumes(
        scans, labels, poses, label_map, 1, clusterer=clusterer, seed=seed, noise_scale=noise_scale
    )
    return track_sequence(vols, scans, poses, label_map, **tracker_kwargs)
