"""The shared stage runner: fingerprint, skip / resume / clear, block execution, finalisation.

Plain functions (no Prefect): the flows wrap :func:`run_block` in a task; tests and benchmarks call
them directly. Callers hold the (sequence, stage) locks of the stage and its downstream stages.
Every function takes the run's typed :class:`~tasks.run_config.RunConfig` (a caller holding a
recorded or hand-made dict converts it once, with :meth:`RunConfig.of`); a block job carries it,
so a block does not read ``run.json`` again.

Resume: a block is complete when its fragment (with the stage's fingerprint) exists; a resumed
stage runs only incomplete blocks, and inside those, items of an array stage whose ``done`` flag
is set (with their row record) are not recomputed. A kill loses at most the item in flight of each
running block (the whole block in flight for a table-only stage such as ingest).

Integrity: a stage whose manifest says done is skipped only when its files pass the store's
cheap check (:meth:`storage.run.RunStore.check_stage`: chunk files and table partitions there
with the sizes recorded when they were written). A damaged stage is **repaired**: each damaged
file is logged, the damaged items are forgotten (record and block fragment) and recomputed by
resuming the stage, every stage downstream of recomputed items is cleared (it was made from the
lost data), and damaged table partitions are rewritten from the block fragments. A stage whose
arrays do not open at all runs fresh.
"""

from __future__ import annotations

import contextlib
import gc
import logging
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

from storage.errors import StoreError
from storage.locks import check_owner
from storage.manifest import BlockFragment, Manifest, fingerprint
from storage.run import Damage, RunStore
from tasks.base import Stage, StageContext
from tasks.pipeline import Pipeline
from tasks.run_config import RunConfig

log = logging.getLogger(__name__)

ITEM_LISTENERS: list = []
"""Called as ``fn(sequence, stage)`` after each item a block in this process computed (progress
bars: blocks running elsewhere, e.g. on Dask workers, report only when they finish)."""


@dataclass(frozen=True)
class BlockJob:
    """One task's work: small and picklable (Dask ships it to a worker, the pipeline's stages with it)."""

    root: str
    storage_options: dict[str, Any]
    pipeline: Pipeline
    sequence: str
    stage: str
    fingerprint: str
    run_id: str
    block: int
    items: tuple[int, ...]
    run: RunConfig


@dataclass
class Decision:
    """What to do with one (sequence, stage)."""

    action: str  # "skip" | "resume" | "repair" | "fresh"
    fingerprint: str
    manifest: Manifest
    jobs: list[BlockJob] = field(default_factory=list)


def resolved_config(stage: Stage, run: RunConfig) -> dict[str, Any]:
    """The stage's config from the run config, validated and with defaults filled in (JSON)."""
    return run.stage_config(stage).model_dump(mode="json")


@contextlib.contextmanager
def frozen_heap() -> Iterator[None]:
    """While a block runs, leave the objects alive at its start (the imported libraries: torch,
    prefect, pydantic, ... hundreds of thousands of them) out of the cyclic garbage collector's
    scans; they go back to its oldest generation afterwards, so nothing is kept alive for longer
    than the block. A full collection over that heap cost ~100 ms, several times per 24 frames of
    the label stages (~10 ms a frame)."""
    gc.freeze()
    try:
        yield
    finally:
        gc.unfreeze()


def make_context(
    store: RunStore, pipeline: Pipeline, sequence: str, stage: str, run: RunConfig, plan: dict | None = None
) -> StageContext:
    spec = pipeline[stage]
    return StageContext(
        store=store,
        sequence=sequence,
        stage=stage,
        config=run.stage_config(spec),
        run=run,
        pipeline=pipeline,
        plan=plan or {},
    )


def upstream_fingerprints(store: RunStore, pipeline: Pipeline, sequence: str, stage: str) -> dict[str, str]:
    """Fingerprints of the finished upstream stages. Raises StoreError if one is not done."""
    out = {}
    for up in pipeline[stage].upstream:
        m = store.read_manifest(sequence, up)
        if m is None or m.status != "done":
            raise StoreError(store.where(sequence, up), f"stage {up!r} is not done")
        out[up] = m.fingerprint
    return out


def stage_fingerprint(store: RunStore, pipeline: Pipeline, sequence: str, stage: str, run: RunConfig) -> str:
    """What a stage's fingerprint would be now (its upstream stages must be done)."""
    spec = pipeline[stage]
    ctx = make_context(store, pipeline, sequence, stage, run)
    upstream = upstream_fingerprints(store, pipeline, sequence, stage)
    return fingerprint(stage, spec.version, resolved_config(spec, run), upstream, spec.inputs(ctx))


def prepare_stage(
    store: RunStore,
    pipeline: Pipeline,
    sequence: str,
    stage: str,
    run: RunConfig,
    run_id: str,
    force: bool = False,
) -> Decision:
    """Decide skip / resume / fresh; on fresh, clear the stage and its downstream and plan it."""
    spec = pipeline[stage]
    ctx = make_context(store, pipeline, sequence, stage, run)
    config = resolved_config(spec, run)
    upstream = upstream_fingerprints(store, pipeline, sequence, stage)
    inputs = spec.inputs(ctx)
    fp = fingerprint(stage, spec.version, config, upstream, inputs)
    old = store.read_manifest(sequence, stage)
    action = "resume"
    if old is not None and old.fingerprint == fp and not force and old.status == "done":
        damage = store.check_stage(sequence, spec.contract, old, flags=True)
        if not damage:
            return Decision("skip", fp, old)
        action = "repair"
        _log_damage(sequence, stage, damage)
        if any(d.whole for d in damage):
            old = None  # cannot be repaired item by item: fresh
        else:
            old.status, old.run_id, old.error = "running", run_id, None
            store.write_manifest(old)  # not done any more before anything is forgotten
            _forget_damaged(store, pipeline, sequence, stage, old, damage)
    if old is not None and old.fingerprint == fp and not force:
        done = store.completed_blocks(sequence, stage, fp)
        jobs = [
            _job(store, pipeline, sequence, stage, fp, run, run_id, b, items)
            for b, items in enumerate(old.blocks)
            if b not in done
        ]
        old.status, old.run_id, old.error = "running", run_id, None
        store.write_manifest(old)
        return Decision(action, fp, old, jobs)
    for name in [stage, *pipeline.downstream_of(stage)]:
        store.clear_stage(sequence, pipeline[name].contract)
    plan = spec.plan(ctx)
    if spec.arrays:
        store.create_arrays(sequence, spec.contract, plan.n_items, plan.max_points, plan.omit, plan.dims)
    size = run.options.block_size
    blocks = [list(range(i, min(i + size, plan.n_items))) for i in range(0, plan.n_items, size)]
    if plan.blocks is not None:
        blocks = [list(b) for b in plan.blocks if b]
    manifest = Manifest(
        stage=stage,
        sequence=sequence,
        fingerprint=fp,
        status="running",
        code_version=spec.version,
        config=config,
        upstream=upstream,
        inputs=inputs,
        run_id=run_id,
        n_items=plan.n_items,
        blocks=blocks,
        plan={"max_points": plan.max_points, "omit": list(plan.omit), "dims": plan.dims, **plan.meta},
        started=time.time(),
    )
    store.write_manifest(manifest)
    jobs = [
        _job(store, pipeline, sequence, stage, fp, run, run_id, b, items) for b, items in enumerate(blocks)
    ]
    return Decision("fresh", fp, manifest, jobs)


def _log_damage(sequence: str, stage: str, damage: list[Damage], shown: int = 10) -> None:
    items = sorted({d.item for d in damage if d.item is not None})
    tables = sorted({d.table for d in damage if d.table is not None})
    log.warning(
        "sequence %s, stage %s is done but damaged (items %s, tables %s): recomputing what was lost",
        sequence, stage, items or "none", tables or "none",
    )  # fmt: skip
    for d in damage[:shown]:
        log.warning("damaged: %s: %s", d.where, d.problem)
    if len(damage) > shown:
        log.warning("damaged: %d more files", len(damage) - shown)


def _forget_damaged(
    store: RunStore, pipeline: Pipeline, sequence: str, stage: str, manifest: Manifest, damage: list[Damage]
) -> None:
    """Make a damaged stage resumable: forget its damaged items (record) and the blocks holding
    them or missing their fragment; clear the stages downstream of recomputed items."""
    items = {d.item for d in damage if d.item is not None}
    blocks = {d.block for d in damage if d.block is not None}
    blocks |= {b for b, its in enumerate(manifest.blocks) if items & set(its)}
    for item in sorted(items):
        store.remove_item_record(sequence, stage, item)
    for b in sorted(blocks):
        store.remove_fragment(sequence, stage, b)
    if items:
        for name in pipeline.downstream_of(stage):
            store.clear_stage(sequence, pipeline[name].contract)


def _job(
    store: RunStore,
    pipeline: Pipeline,
    sequence: str,
    stage: str,
    fp: str,
    run: RunConfig,
    run_id: str,
    b: int,
    items,
) -> BlockJob:
    return BlockJob(
        store.uri, store.storage_options, pipeline, sequence, stage, fp, run_id, b, tuple(items), run
    )


def run_block(job: BlockJob, store: RunStore | None = None) -> dict[str, Any]:
    """Compute one block: items' arrays (``done`` last), then the block fragment. Returns a small dict."""
    t0 = time.perf_counter()
    store = store or RunStore(job.root, job.storage_options)
    manifest = store.read_manifest(job.sequence, job.stage)
    if manifest is None or manifest.fingerprint != job.fingerprint:
        raise StoreError(store.where(job.sequence, job.stage), "stage changed under this block")
    ctx = make_context(store, job.pipeline, job.sequence, job.stage, job.run, manifest.plan)
    spec = job.pipeline[job.stage]
    arrays = store.arrays(job.sequence, spec.contract, read_only=False) if spec.arrays else None
    rows: dict[str, list[dict]] = {}
    counts: dict[str, int] = {}
    records: dict[int, dict[str, Any]] = {}

    def add(item_rows: dict[str, list[dict]], item_counts: dict[str, int]) -> None:
        for table, rs in item_rows.items():
            rows.setdefault(table, []).extend(rs)
        for key, n in item_counts.items():
            counts[key] = counts.get(key, 0) + n

    todo = list(job.items)
    if arrays is not None:  # items of an interrupted block whose done flag is set are not recomputed
        kept = []  # a repair forgot its damaged items' records: a damaged done flag is not read
        for item in job.items:
            record = store.read_item_record(job.sequence, job.stage, item)
            if (
                record is not None
                and record.get("fingerprint") == job.fingerprint
                and arrays.check_done_flag(item) is None
                and arrays.files_intact(item, record)
            ):
                add(record["rows"], record["counts"])
                records[item] = {"n_points": record["n_points"], "chunks": record["chunks"]}
            else:
                kept.append(item)
        todo = kept
    with frozen_heap():
        for res in spec.run_block(ctx, todo):
            if arrays is not None:
                records[res.index] = _write_item(store, job, arrays, res)
            add(res.rows, res.counts)
            for fn in list(ITEM_LISTENERS):
                fn(job.sequence, job.stage)
    check_owner(store.root, store.lock_rel(job.sequence, job.stage), job.run_id)
    frag = BlockFragment(
        fingerprint=job.fingerprint,
        block=job.block,
        items=list(job.items),
        seconds=time.perf_counter() - t0,
        counts=counts,
        rows=rows,
        records=records,
    )
    store.write_fragment(job.sequence, job.stage, frag)
    return {
        "sequence": job.sequence,
        "stage": job.stage,
        "block": job.block,
        "seconds": frag.seconds,
        "items_resumed": len(job.items) - len(todo),
        **counts,
    }


def _write_item(store: RunStore, job: BlockJob, arrays, res) -> dict[str, Any]:
    """Write one item's arrays, its record (rows, counts, chunk records) before its ``done`` flag."""
    record = {"fingerprint": job.fingerprint, "rows": res.rows, "counts": res.counts}

    def before_done(chunks: dict[str, Any]) -> None:
        store.write_item_record(job.sequence, job.stage, res.index, {**record, **chunks})

    return arrays.write_item(res.index, res.arrays, res.n_points, before_done)


def finalize_stage(store: RunStore, pipeline: Pipeline, sequence: str, stage: str, fp: str) -> Manifest:
    """Gather the block fragments into the tables and write the manifest as done (last)."""
    manifest = store.read_manifest(sequence, stage)
    if manifest is None or manifest.fingerprint != fp:
        raise StoreError(store.where(sequence, stage), "manifest changed before finalise")
    frags = store.fragments(sequence, stage, fp, rows=True)
    missing = sorted(set(range(len(manifest.blocks))) - set(frags))
    if missing:
        raise StoreError(store.where(sequence, stage), f"blocks {missing} are not done")
    ordered = [frags[b] for b in sorted(frags)]
    for spec in pipeline[stage].tables:
        rows = [r for f in ordered for r in f.rows.get(spec.name, [])]
        rows.sort(key=lambda r: r.get("index", 0))
        manifest.tables[spec.name] = store.write_table(sequence, spec, rows)
    counts: dict[str, int] = {}
    for f in ordered:
        for key, n in f.counts.items():
            counts[key] = counts.get(key, 0) + n
    manifest.counts = counts
    manifest.blocks_done = sorted(frags)
    manifest.finished = time.time()
    manifest.timings = {
        "wall_s": manifest.finished - manifest.started,
        "block_s": sum(f.seconds for f in ordered),
    }
    manifest.status = "done"
    store.write_manifest(manifest)
    return manifest


def mark_failed(store: RunStore, sequence: str, stage: str, fp: str, error: str) -> None:
    m = store.read_manifest(sequence, stage)
    if m is not None and m.fingerprint == fp and m.status != "done":
        m.status, m.error = "failed", error[:2000]
        store.write_manifest(m)


def run_stage_plain(
    store: RunStore,
    pipeline: Pipeline,
    sequence: str,
    stage: str,
    run: RunConfig,
    run_id: str,
    force: bool = False,
) -> Manifest:
    """Prepare, run every block in a loop, finalise (no Prefect, no locks, errors raise).

    For tests, benchmarks and ``dsnet adapt``'s teacher: its stores lie inside the adapt output
    folder, which the command holds with its writer lock (``flows.commands.model_folder``), and a
    failing stage fails the adaptation (``dsnet label``'s ``fail`` policy). ``dsnet label``'s stage
    loop (Prefect tasks, per-(sequence, stage) locks, the ``skip`` policy) is
    :func:`flows.stage_loop.run_stage`, which tasks cannot import.
    """
    decision = prepare_stage(store, pipeline, sequence, stage, run, run_id, force)
    if decision.action == "skip":
        return decision.manifest
    for job in decision.jobs:
        run_block(job, store)
    return finalize_stage(store, pipeline, sequence, stage, decision.fingerprint)


def stage_state(
    store: RunStore,
    pipeline: Pipeline,
    sequence: str,
    stage: str,
    run: RunConfig | None = None,
    full: bool = False,
) -> tuple[str, Manifest | None, int]:
    """(state, manifest, finished blocks) for ``dsnet status``, from the store alone.

    state: ``done``; ``damaged`` (done, but its files fail the store's cheap check: a rerun
    recomputes what was lost); ``partial`` (running/failed); ``stale`` (an upstream stage now has
    another fingerprint, or the run config asks for another config); ``missing``. ``full``:
    decode and hash every chunk and table file instead of the cheap check.
    """
    m = store.read_manifest(sequence, stage)
    if m is None:
        return "missing", None, 0
    if m.status != "done":
        return "partial", m, len(store.completed_blocks(sequence, stage, m.fingerprint))
    for up, fp in m.upstream.items():
        um = store.read_manifest(sequence, up)
        if um is None or um.fingerprint != fp:
            return "stale", m, len(m.blocks)
    if run is not None and resolved_config(pipeline[stage], run) != m.config:
        return "stale", m, len(m.blocks)
    if store.check_stage(sequence, pipeline[stage].contract, m, full=full):
        return "damaged", m, len(m.blocks)
    return "done", m, len(m.blocks)
