"""A stand-in labels stage for scoring tests: perturbed ground truth through the real store.

It declares the final-label array the score stage reads (item = frame, per-point ``label`` uint32
in the scan's point order) and a ``tracks`` table with a confidence per instance, and runs through
the real runner (zarr arrays, block fragments, parquet, manifests). The perturbation is
deterministic: per frame a seeded share of points gets another class, and in odd frames one
instance is split in two ids. :data:`ORACLE` is a method made of ingest, this stage and score:
tests pass it where a pipeline is taken, nothing is patched.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pyarrow as pa

from dsnet_core.labels import class_map_of, load_label_map
from storage.contract import TableSpec
from tasks.base import CLASS_MAP, FRAME_LABEL, ItemResult, Plan, Stage, StageConfig, StageContext
from tasks.ingest import IngestStage
from tasks.pipeline import Pipeline
from tasks.score import ScoreStage

LM = load_label_map("semantic-kitti")
TRACKS = TableSpec(  # the review queue reads the columns declared in ``roles``
    "oracle_tracks",
    pa.schema(
        [
            ("id", pa.int32()),
            ("class_id", pa.int32()),
            ("first_frame", pa.int32()),
            ("n_points", pa.int64()),
            ("confidence", pa.float64()),
        ]
    ),
    roles=(("id", "id"), ("class_id", "class_id"), ("points", "n_points"), ("item", "first_frame"),
           ("confidence", "confidence")),
)  # fmt: skip


class OracleStitchConfig(StageConfig):
    noise: float = 0.05  # share of points given another class
    seed: int = 0


def perturb(labels: np.ndarray, index: int, noise: float, seed: int) -> np.ndarray:
    """Ground truth ``(N,) uint32`` -> a deterministic perturbed prediction ``(N,) uint32``."""
    rng = np.random.default_rng([seed, index])
    out = labels.astype(np.uint32).copy()
    flip = rng.random(out.size) < noise
    out[flip] = (out[flip] & 0xFFFF0000) | np.uint32(40)  # -> road
    inst = out >> 16
    ids = np.unique(inst[inst > 0])
    if index % 2 and ids.size:
        sel = np.flatnonzero(inst == ids[0])
        half = sel[: sel.size // 2]
        out[half] = (out[half] & 0xFFFF) | np.uint32((int(ids[0]) + 500) << 16)
    return out


class OracleStitch(Stage):
    name = "oracle"
    upstream = ("ingest",)
    version = "oracle-1"
    Config = OracleStitchConfig
    item = "frame"
    arrays = (FRAME_LABEL,)
    tables = (TRACKS,)

    def plan(self, ctx: StageContext) -> Plan:
        n = ctx.frames["n_points"].to_pylist()
        return Plan(n_items=len(n), max_points=max(n, default=0), meta={CLASS_MAP: class_map_of(LM)})

    def run_block(self, ctx: StageContext, items: list[int]) -> Iterator[ItemResult]:
        reader = ctx.reader
        refs = reader.frames(ctx.sequence)
        for i in items:
            gt = reader.labels(refs[i])
            if gt is None:  # a log without ground truth: predict "unlabeled" everywhere
                gt = np.zeros(reader.scan(refs[i]).shape[0], dtype=np.uint32)
            pred = perturb(gt, i, ctx.config.noise, ctx.config.seed)
            inst = pred >> 16
            tracks = [
                {
                    "id": int(t),
                    "class_id": LM.learning_map[int(pred[inst == t][0] & 0xFFFF)],
                    "first_frame": i,
                    "n_points": int((inst == t).sum()),
                    "confidence": round(0.2 + 0.8 * ((int(t) * 37 + i) % 100) / 100, 3),
                }
                for t in np.unique(inst[inst > 0])
            ]
            yield ItemResult(
                i,
                arrays={"label": pred},
                n_points=int(pred.size),
                rows={"oracle_tracks": tracks},
                counts={"frames": 1, "points": int(pred.size)},
            )


ORACLE = Pipeline("oracle", (IngestStage(), OracleStitch(), ScoreStage(labels="oracle")), labels="oracle")


def score_runs(root, log, runs: dict[str, float], sequences=("00", "01"), block_size: int = 4, bev: int = 3):
    """Label (oracle stage with the given noise) and score one run store per entry of ``runs``
    (``{name: noise}``) under ``root``; returns their URIs."""
    from flows.report import write_report
    from storage.run import RunStore
    from tests.helpers.plain_runner import run_stage_plain

    out = []
    for name, noise in runs.items():
        store = RunStore(f"{root}/{name}")
        run = {
            "data": str(log),
            **ORACLE.record(),
            "stages": {"oracle": {"noise": noise}},
            "options": {"block_size": block_size},
        }
        store.write_run_config(name, run)
        for seq in sequences:
            for stage in ORACLE.names():
                run_stage_plain(store, ORACLE, seq, stage, run, name)
        write_report(store, ORACLE, bev_frames=bev, review_rows=8)
        out.append(store.uri)
    return out
