"""One run-config builder (:func:`tasks.run_config.build_run_config`): ``dsnet label``'s request and
``dsnet adapt``'s teacher build their run configs through it, and what it builds records the same
bytes the hand-built configs recorded before."""

from __future__ import annotations

import json
from pathlib import Path

from flows.request import LabelRequest
from tasks.base import RunOptions
from tasks.methods import get_pipeline
from tasks.run_config import RunConfig, build_run_config


def _dumped(run: RunConfig) -> str:
    return json.dumps(run.model_dump(mode="json", exclude={"run_id", "store_format"}))


def test_the_request_builds_through_the_shared_builder(tmp_path: Path) -> None:
    request = LabelRequest(
        data=str(tmp_path / "log"),
        root=str(tmp_path / "run"),
        reader_options={"sweeps": True},
        stages={"align": {"scans": 3}},
        options=RunOptions(block_size=7),
    )
    pipeline = request.pipeline()
    got = request.run_config(pipeline, "semantickitti", ["00", "01"], run_id="r9", code_version="v1")
    want = build_run_config(
        pipeline,
        str((tmp_path / "log").resolve()),
        "semantickitti",
        reader_options={"sweeps": True},
        sequences=["00", "01"],
        stages=request.stage_configs(pipeline, request.order(pipeline)),
        options=RunOptions(block_size=7),
        run_id="r9",
        code_version="v1",
    )
    assert got == want
    assert got.reader_options == {"sweeps": True} and got.options.block_size == 7
    assert got.stages["align"]["scans"] == 3
    assert (got.method, got.labels_stage) == (pipeline.name, pipeline.labels)


def test_the_teachers_config_records_the_bytes_of_the_old_hand_built_one() -> None:
    """The teacher's stores keep their run.json (and so their fingerprints) across the change."""
    pipeline = get_pipeline(refine=True)
    stages = {"ingest": {"grid": [0.05, 0.05, 0.05]}, "align": {"scans": 2}}
    by_hand = RunConfig(  # what the teacher built by hand before the shared builder
        data="/logs/a",
        format="semantickitti",
        sequences=["00"],
        stages=stages,
        run_id="adapt-round1",
        **pipeline.record(),
    )
    built = build_run_config(
        pipeline, "/logs/a", "semantickitti", reader_options={}, sequences=["00"], stages=stages,
        run_id="adapt-round1",
    )  # fmt: skip
    assert _dumped(built) == _dumped(by_hand)
    assert built == by_hand
