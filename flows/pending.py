"""What a labelling request would compute, decided from the store's manifests alone (no Prefect):
``dsnet label`` skips starting a server when nothing is pending, and ``dsnet serve``'s ticks label
only the sequences that are new or stale."""

from __future__ import annotations

from flows.request import LabelRequest, resolved_location
from storage.errors import StoreError
from storage.run import RunStore
from tasks.run_config import RunConfig
from tasks.runner import stage_fingerprint

__all__ = ["pending_sequences", "resolved_location"]


def pending_sequences(request: LabelRequest, sequences: list[str] | None = None) -> list[str]:
    """The sequences (of ``sequences``, default the request's or the log's) for which a run of
    ``request`` would compute some stage: one not finished, finished with another fingerprint (its
    config, code version, inputs or upstream changed), or damaged. ``force`` and ``from_stage``
    make every sequence pending."""
    pipeline = request.pipeline()
    reader = request.open_log()
    if sequences is None:
        sequences = request.sequences if request.sequences is not None else reader.sequences()
    if request.force or request.from_stage:
        return list(sequences)
    store = RunStore(request.root, request.storage_options)
    run = request.run_config(pipeline, reader.format)
    if not _report_intact(store):  # the run writes its config and report again: every sequence
        return list(sequences)
    return [seq for seq in sequences if not _finished(store, pipeline, request.order(pipeline), seq, run)]


def _report_intact(store: RunStore) -> bool:
    """Whether what a run writes besides its stages is there and undamaged: the run config
    (``run.json``), every report table the store has (its digest against its record: they are
    small, one row per frame at most) and the dashboard. A run answered "nothing to do" rewrites
    none of them."""
    from flows.report.tables import REPORT_TABLES
    from storage.run import DASHBOARD

    try:
        store.read_run_config()
        damaged = any(
            store.check_run_table(s, full=True) for s in REPORT_TABLES.values() if store.has_table(s)
        )
    except (StoreError, ValueError):
        return False
    return not damaged and store.root.size(DASHBOARD) is not None


def _finished(store: RunStore, pipeline, order: list[str], sequence: str, run: RunConfig) -> bool:
    """Whether every stage of ``order`` is done and current. Read without the run's locks: another
    run may be changing the store meanwhile, so anything unreadable or in flux counts as pending
    (the run itself then decides under its locks)."""
    try:
        for stage in order:
            m = store.read_manifest(sequence, stage)
            if m is None or m.status != "done":
                return False
            if stage_fingerprint(store, pipeline, sequence, stage, run) != m.fingerprint:
                return False
            if store.check_stage(sequence, pipeline[stage].contract, m, flags=True):
                return False
    except StoreError:  # e.g. an upstream stage cleared by a concurrent run between two reads
        return False
    return True
