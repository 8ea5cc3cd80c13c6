"""A new stage through the public interface only: declare it, put it in a pipeline, run and resume.

Nothing is patched: the stage declares its arrays and table, the pipeline lists it after ingest,
and the runner does the rest (zarr arrays, table, manifest, skip and resume).
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pyarrow as pa
import pytest

from storage.contract import ArraySpec, TableSpec
from storage.run import RunStore
from tasks.base import FRAME_LABEL, ItemResult, Plan, Stage, StageConfig, StageContext
from tasks.ingest import IngestStage
from tasks.pipeline import Pipeline
from tests.helpers.plain_runner import finalize_stage, prepare_stage, run_block, run_stage_plain

RANGES = TableSpec("toy_ranges", pa.schema([("index", pa.int32()), ("max_range", pa.float32())]))


class RangeConfig(StageConfig):
    scale: float = 1.0


class RangeStage(Stage):
    """Per point: its range (metres, times ``scale``); per frame: the largest."""

    name = "toy_range"
    upstream = ("ingest",)
    version = "1"
    Config = RangeConfig
    item = "frame"
    arrays = (ArraySpec("range", "float32", doc="distance from the sensor, metres"), FRAME_LABEL)
    tables = (RANGES,)

    def plan(self, ctx: StageContext) -> Plan:
        n = ctx.frames["n_points"].to_pylist()
        return Plan(n_items=len(n), max_points=max(n), meta={"n": n})

    def run_block(self, ctx: StageContext, items: list[int]) -> Iterator[ItemResult]:
        refs = ctx.reader.frames(ctx.sequence)
        for i in items:
            xyz = ctx.reader.scan(refs[i])[:, :3]
            r = np.linalg.norm(xyz, axis=1) * ctx.config.scale
            label = np.full(r.shape, 40, np.uint32)  # everything "road": a labels stage of a kind
            yield ItemResult(
                i,
                arrays={"range": r, "label": label},
                n_points=r.size,
                rows={"toy_ranges": [{"index": i, "max_range": float(r.max())}]},
                counts={"frames": 1, "points": int(r.size)},
            )


TOY = Pipeline("toy", (IngestStage(), RangeStage()), labels="toy_range")


def _run(log) -> dict:
    return {"data": str(log), "stages": {}, "options": {"block_size": 2}}


def test_a_new_stage_runs_skips_and_resumes(synth_log, tmp_path):
    run = _run(synth_log)
    full = RunStore(tmp_path / "full")
    full.write_run_config("r1", run)
    for stage in TOY.names():
        m = run_stage_plain(full, TOY, "00", stage, run, "r1")
    assert m.status == "done" and m.n_items == 6 and len(m.blocks) == 3
    assert prepare_stage(full, TOY, "00", "toy_range", run, "r1").action == "skip"

    # interrupted after one block: the next run resumes only the missing blocks
    part = RunStore(tmp_path / "part")
    part.write_run_config("r1", run)
    run_stage_plain(part, TOY, "00", "ingest", run, "r1")
    first = prepare_stage(part, TOY, "00", "toy_range", run, "r1")
    run_block(first.jobs[0], part)
    again = prepare_stage(part, TOY, "00", "toy_range", run, "r1")
    assert again.action == "resume" and [j.block for j in again.jobs] == [1, 2]
    for job in again.jobs:
        run_block(job, part)
    finalize_stage(part, TOY, "00", "toy_range", again.fingerprint)

    contract = TOY["toy_range"].contract
    a, b = full.arrays("00", contract), part.arrays("00", contract)
    for i in range(6):
        assert np.array_equal(a.read_item(i)["range"], b.read_item(i)["range"])
    assert full.read_table("00", RANGES).equals(part.read_table("00", RANGES))
    # a config change re-plans the stage, not ingest
    scaled = {**run, "stages": {"toy_range": {"scale": 2.0}}}
    assert prepare_stage(full, TOY, "00", "ingest", scaled, "r2").action == "skip"
    assert prepare_stage(full, TOY, "00", "toy_range", scaled, "r2").action == "fresh"


def test_a_pipeline_checks_its_stage_order():
    with pytest.raises(ValueError, match="reads \\['ingest'\\], not run before it"):
        Pipeline("bad", (RangeStage(), IngestStage()), labels="toy_range")
    with pytest.raises(ValueError, match="declares no FRAME_LABEL"):
        Pipeline("bad", (IngestStage(), RangeStage()), labels="ingest")
    with pytest.raises(ValueError, match="unknown stage 'shift'"):
        TOY.check_stage("shift")
