"""The run store: one root holding the run config and, per (sequence, stage), a manifest, block
fragments, a zarr group, a lock and the stage's small state; tables under ``tables/``.

Every path of the store is built here. Layout::

    ROOT/run.json                                  resolved run config + code version (latest run)
    ROOT/runs/<run_id>.json                        every run's config and summary
    ROOT/sequences/<seq>/<stage>/manifest.json     written last, atomically
    ROOT/sequences/<seq>/<stage>/blocks/NNNNN.json one fragment per finished block
    ROOT/sequences/<seq>/<stage>/blocks/<name>     a block's own bytes (e.g. score accumulators)
    ROOT/sequences/<seq>/<stage>/items/NNNNNN.json rows + counts of one item (array stages), before done
    ROOT/sequences/<seq>/<stage>/arrays.zarr/      padded per-item arrays (zarr v3)
    ROOT/sequences/<seq>/<stage>/state.json        a sequential stage's resume state (e.g. the stitcher)
    ROOT/sequences/<seq>/<stage>/lock.json         owner + heartbeat
    ROOT/tables/<table>/sequence=<seq>/part-0.parquet   stage tables, one partition per sequence
    ROOT/tables/<table>/part-0.parquet                  report tables (not partitioned)
    ROOT/dashboard.html                            the run's dashboard

Stages declare their arrays and tables (:class:`~storage.contract.StageContract`); the store takes
those declarations as arguments and knows no stage by name.
"""

from __future__ import annotations

import posixpath
from pathlib import Path
from typing import Any

from storage.arrays import StageArrays
from storage.contract import StageContract, TableSpec
from storage.errors import StoreError
from storage.fs import RootFS
from storage.manifest import BlockFragment, Manifest
from storage.names import check_plain_name
from storage.tables import read_partition, read_table, remove_partition, to_table, write_partition

DASHBOARD = "dashboard.html"


class RunStore:
    """A run store under ``uri`` (local path or ``s3://…``)."""

    def __init__(self, uri: str | Path, storage_options: dict[str, Any] | None = None) -> None:
        self.root = RootFS(uri, storage_options)

    @property
    def uri(self) -> str:
        return self.root.uri

    @property
    def storage_options(self) -> dict[str, Any]:
        return self.root.storage_options

    # -- run config ----------------------------------------------------------------------------
    def write_run_config(self, run_id: str, config: dict[str, Any]) -> None:
        self.root.write_json("run.json", {"run_id": run_id, **config})
        self.root.write_json(f"runs/{run_id}.json", {"run_id": run_id, **config})

    def read_run_config(self, run_id: str | None = None) -> dict[str, Any]:
        """The latest run's config, or that of ``run_id``."""
        rel = "run.json" if run_id is None else f"runs/{run_id}.json"
        cfg = self.root.read_json(rel)
        if cfg is None:
            raise StoreError(self.root.url(rel), "no run config here (not a run store, or unknown run)")
        return cfg

    def update_run_record(self, run_id: str, **fields: Any) -> None:
        rec = self.root.read_json(f"runs/{run_id}.json") or {"run_id": run_id}
        rec.update(fields)
        self.root.write_json(f"runs/{run_id}.json", rec)

    def sequences(self) -> list[str]:
        return self.root.listdir("sequences")

    # -- per (sequence, stage) ---------------------------------------------------------------
    @staticmethod
    def stage_rel(sequence: str, stage: str) -> str:
        return posixpath.join("sequences", check_plain_name(sequence), check_plain_name(stage, "stage name"))

    def where(self, sequence: str, stage: str) -> str:
        """The URL of a stage's folder (for error messages)."""
        return self.root.url(self.stage_rel(sequence, stage))

    def lock_rel(self, sequence: str, stage: str) -> str:
        """Where the lock of a (sequence, stage) lives (see :mod:`storage.locks`)."""
        return posixpath.join(self.stage_rel(sequence, stage), "lock.json")

    def read_manifest(self, sequence: str, stage: str) -> Manifest | None:
        data = self.root.read_json(posixpath.join(self.stage_rel(sequence, stage), "manifest.json"))
        return None if data is None else Manifest.model_validate(data)

    def write_manifest(self, manifest: Manifest) -> None:
        rel = posixpath.join(self.stage_rel(manifest.sequence, manifest.stage), "manifest.json")
        self.root.write_bytes(rel, manifest.model_dump_json(indent=1).encode())

    def write_fragment(self, sequence: str, stage: str, fragment: BlockFragment) -> None:
        rel = posixpath.join(self.stage_rel(sequence, stage), "blocks", f"{fragment.block:05d}.json")
        self.root.write_bytes(rel, fragment.model_dump_json().encode())

    def fragments(self, sequence: str, stage: str, fingerprint: str) -> dict[int, BlockFragment]:
        """Finished blocks of the stage with this fingerprint."""
        base = posixpath.join(self.stage_rel(sequence, stage), "blocks")
        out = {}
        for name in self.root.listdir(base):
            if not name.endswith(".json") or name.startswith("."):
                continue
            data = self.root.read_json(posixpath.join(base, name))
            if data is None:
                continue
            frag = BlockFragment.model_validate(data)
            if frag.fingerprint == fingerprint:
                out[frag.block] = frag
        return out

    def completed_blocks(self, sequence: str, stage: str, fingerprint: str) -> set[int]:
        return set(self.fragments(sequence, stage, fingerprint))

    def block_bytes_rel(self, sequence: str, stage: str, name: str) -> str:
        return posixpath.join(self.stage_rel(sequence, stage), "blocks", name)

    def write_block_bytes(self, sequence: str, stage: str, name: str, data: bytes) -> None:
        """A block's own output beside its fragment (written before the fragment)."""
        self.root.write_bytes(self.block_bytes_rel(sequence, stage, name), data)

    def read_block_bytes(self, sequence: str, stage: str, name: str) -> bytes:
        """Raises StoreError when missing."""
        rel = self.block_bytes_rel(sequence, stage, name)
        data = self.root.read_bytes(rel)
        if data is None:
            raise StoreError(self.root.url(rel), "block output missing")
        return data

    def write_item_record(self, sequence: str, stage: str, index: int, record: dict[str, Any]) -> None:
        """One item's table rows and counts, written before its ``done`` flag (item-level resume)."""
        rel = posixpath.join(self.stage_rel(sequence, stage), "items", f"{index:06d}.json")
        self.root.write_json(rel, record)

    def read_item_record(self, sequence: str, stage: str, index: int) -> dict[str, Any] | None:
        return self.root.read_json(
            posixpath.join(self.stage_rel(sequence, stage), "items", f"{index:06d}.json")
        )

    def read_stage_state(self, sequence: str, stage: str) -> dict[str, Any] | None:
        """A sequential stage's saved resume state, or None."""
        return self.root.read_json(posixpath.join(self.stage_rel(sequence, stage), "state.json"))

    def write_stage_state(self, sequence: str, stage: str, state: dict[str, Any] | None) -> None:
        """Save (or, with None, remove) a sequential stage's resume state."""
        rel = posixpath.join(self.stage_rel(sequence, stage), "state.json")
        if state is None:
            self.root.remove(rel)
        else:
            self.root.write_json(rel, state)

    def create_arrays(
        self, sequence: str, contract: StageContract, n_items: int, max_points: int, omit=(), dims=None
    ) -> StageArrays:
        rel = posixpath.join(self.stage_rel(sequence, contract.stage), "arrays.zarr")
        return StageArrays.create(self.root, rel, contract, n_items, max_points, omit, dims)

    def arrays(self, sequence: str, contract: StageContract, read_only: bool = True) -> StageArrays:
        rel = posixpath.join(self.stage_rel(sequence, contract.stage), "arrays.zarr")
        return StageArrays.open(self.root, rel, contract, read_only=read_only)

    def write_table(self, sequence: str, spec: TableSpec, rows: list[dict[str, Any]]) -> str:
        return write_partition(self.root, spec, {"sequence": sequence}, to_table(spec, rows))

    def read_table(self, sequence: str, spec: TableSpec):
        """One sequence's partition of a stage's table (a pyarrow Table)."""
        return read_partition(self.root, spec, {"sequence": sequence})

    def clear_stage(self, sequence: str, contract: StageContract) -> None:
        """Remove a stage's outputs. The manifest goes first, so a reader never sees "done" over
        missing data; the lock file stays."""
        base = self.stage_rel(sequence, contract.stage)
        self.root.remove(posixpath.join(base, "manifest.json"))
        for spec in contract.tables:
            remove_partition(self.root, spec, {"sequence": sequence})
        self.root.remove(posixpath.join(base, "blocks"), recursive=True)
        self.root.remove(posixpath.join(base, "items"), recursive=True)
        self.root.remove(posixpath.join(base, "arrays.zarr"), recursive=True)
        self.root.remove(posixpath.join(base, "state.json"))

    # -- whole-run tables ------------------------------------------------------------------------
    def has_table(self, spec: TableSpec) -> bool:
        return self.root.exists(posixpath.join("tables", spec.name))

    def table_url(self, spec: TableSpec) -> str:
        """Where a table lives (for messages)."""
        return self.root.url(posixpath.join("tables", spec.name))

    def write_run_table(self, spec: TableSpec, rows: list[dict[str, Any]]) -> str:
        """An unpartitioned table (``tables/<name>/part-0.parquet``), rewritten whole."""
        return write_partition(self.root, spec, {}, to_table(spec, rows))

    def read_all(self, spec: TableSpec):
        """A whole table, partition columns included as strings (a pyarrow Table).

        Raises:
            StoreError: the table was never written.
        """
        if not self.has_table(spec):
            raise StoreError(self.table_url(spec), "table not written yet")
        return read_table(self.root, spec)

    # -- the dashboard ---------------------------------------------------------------------------
    def write_dashboard(self, page: bytes) -> str:
        """Write ``ROOT/dashboard.html``; returns its location."""
        self.root.write_bytes(DASHBOARD, page)
        return self.root.path(DASHBOARD) if self.root.local else self.root.url(DASHBOARD)
