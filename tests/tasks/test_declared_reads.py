"""Stages declare every stage they read: the context refuses the others, the pipeline checks that a
declared read is covered by the stage's fingerprint and declares the arrays; per-frame values of a
volume stage come from one helper (:class:`tasks.frames.FrameValues`) that agrees with
:func:`dsnet_core.temporal.align.split_volume` and inverts it."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest

from dsnet_core.temporal.align import split_volume
from storage.errors import StoreError
from storage.run import RunStore
from tasks.align import AlignStage
from tasks.base import FRAME_LABEL, ItemResult, Plan, Stage, StageContext
from tasks.frames import FrameValues
from tasks.ingest import IngestStage
from tasks.methods import get_pipeline
from tasks.pipeline import Pipeline
from tests.helpers.plain_runner import make_context, run_stage_plain
from tests.tasks.test_toy_stage import RangeStage


class Reader(Stage):
    """Reads ``toy_range``'s ranges: declared by ``reads`` or not at all (``declare``)."""

    name = "toy_reader"
    upstream = ("toy_label",)
    version = "1"
    arrays = (FRAME_LABEL,)

    def __init__(self, declare: bool, source: str = "toy_range") -> None:
        self.declare, self.source = declare, source

    def reads(self, pipeline) -> dict[str, tuple[str, ...]]:
        return {self.source: ("range",)} if self.declare else {}

    def plan(self, ctx: StageContext) -> Plan:
        return Plan(n_items=0)

    def run_block(self, ctx: StageContext, items: list[int]) -> Iterator[ItemResult]:
        yield from ()


class Label(RangeStage):
    name = "toy_label"
    upstream = ("toy_range",)


def _pipeline(declare: bool, source: str = "toy_range") -> Pipeline:
    return Pipeline("t", (IngestStage(), RangeStage(), Label(), Reader(declare, source)), labels="toy_reader")


def test_an_undeclared_read_is_refused_and_a_declared_one_is_checked(tmp_path):
    run = {"data": "unused", "stages": {}}
    store = RunStore(tmp_path / "s")
    ctx = make_context(store, _pipeline(False), "00", "toy_reader", run)
    with pytest.raises(StoreError, match="reads stage 'toy_range' without declaring it"):
        ctx.arrays("toy_range")
    with pytest.raises(StoreError, match="without declaring it"):
        ctx.table("toy_range", "toy_ranges")
    declared = make_context(store, _pipeline(True), "00", "toy_reader", run)
    with pytest.raises(StoreError, match="no arrays of stage 'toy_range'"):  # allowed: it has not run
        declared.arrays("toy_range")
    with pytest.raises(ValueError, match="reads arrays \\['range'\\] of stage 'ingest'"):
        _pipeline(True, "ingest")
    lone = Reader(True)
    lone.upstream = ("ingest",)  # toy_range is not upstream of ingest: no fingerprint covers it
    with pytest.raises(ValueError, match="reads 'toy_range', which is not upstream of what it reads"):
        Pipeline("t", (IngestStage(), RangeStage(), lone), labels="toy_reader")


def test_every_method_declares_what_its_stages_read():
    shift = get_pipeline("dsnet")["shift"]
    assert shift.sources(get_pipeline("dsnet")) == {"infer", "align"}
    refine = get_pipeline("dsnet", refine=True)
    assert refine["refine"].reads(refine) == {"infer": ("probs",), "align": ("source_frame", "source_index")}
    assert get_pipeline("most", refine=True)["refine"].reads(get_pipeline("most", refine=True)) == {}


def test_frame_values_split_and_gather_volumes(synth_log, tmp_path):
    p = Pipeline("a", (IngestStage(), AlignStage(), RangeStage()), labels="toy_range")  # labels: any
    run = {"data": str(synth_log), "stages": {"align": {"scans": 3, "stride": 2}}}
    store = RunStore(tmp_path / "s")
    store.write_run_config("r1", run)
    for stage in ("ingest", "align"):
        run_stage_plain(store, p, "00", stage, run, "r1")
    values = FrameValues.near(store, p, "00", "align")  # the mapping stage itself
    assert values.mapping == "align" and values.frames() == list(range(6))
    assert values.windows == [[0, 1, 2], [2, 3, 4], [3, 4, 5]]
    assert [values.owner[f] for f in range(6)] == [0, 0, 0, 1, 1, 2]  # the first volume holding it
    align = store.arrays("00", p["align"].contract)
    for f in range(6):
        v = values.owner[f]
        vol = align.read_item(v)
        want = split_volume(vol["points"], vol["source_frame"], vol["source_index"])[f]
        assert np.array_equal(values.frame(align, f, ["points"])["points"], want)
    for v in range(3):  # gather inverts the split of each volume
        vol = align.read_item(v)
        scans = split_volume(vol["points"], vol["source_frame"], vol["source_index"])
        back, n = values.gather(v, scans.__getitem__)
        assert n == back.shape[0] and np.array_equal(back, vol["points"])
    assert values.frame(align, 9, ["points"]) is None
