"""Run every stage of a pipeline on one sequence with the plain runner (no Prefect)."""

from __future__ import annotations

from storage.run import RunStore
from tasks.pipeline import Pipeline
from tests.helpers.plain_runner import run_stage_plain


def run_all_stages(
    store: RunStore, pipeline: Pipeline, run: dict, run_id: str = "r1", sequence: str = "00"
) -> dict:
    """Record ``run`` (with the pipeline's record: method, options, labels stage) as run ``run_id``
    and run each stage in order; returns the manifests by stage."""
    run = {**pipeline.record(), **run}
    store.write_run_config(run_id, run)
    return {s.name: run_stage_plain(store, pipeline, sequence, s.name, run, run_id) for s in pipeline}
