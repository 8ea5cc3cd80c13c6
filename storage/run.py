"""The run store: one root holding the run config and, per (sequence, stage), a manifest, block
fragments, a zarr group and a lock; tables under ``tables/``.

Layout::

    ROOT/run.json                                  resolved run config + code version (latest run)
    ROOT/runs/<run_id>.json                        every run's config and summary
    ROOT/sequences/<seq>/<stage>/manifest.json     written last, atomically
    ROOT/sequences/<seq>/<stage>/blocks/NNNNN.json one fragment per finished block
    ROOT/sequences/<seq>/<stage>/items/NNNNNN.json rows + counts of one item (array stages), before done
    ROOT/sequences/<seq>/<stage>/arrays.zarr/      padded per-item arrays (zarr v3)
    ROOT/sequences/<seq>/<stage>/lock.json         owner + heartbeat
    ROOT/tables/<table>/sequence=<seq>/part-0.parquet
"""

from __future__ import annotations

import posixpath
from pathlib import Path
from typing import Any

from storage.arrays import StageArrays
from storage.contract import CONTRACTS
from storage.errors import StoreError
from storage.fs import RootFS
from storage.manifest import BlockFragment, Manifest
from storage.tables import read_partition, remove_partition, to_table, write_partition


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
        return posixpath.join("sequences", sequence, stage)

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

    def write_item_record(self, sequence: str, stage: str, index: int, record: dict[str, Any]) -> None:
        """One item's table rows and counts, written before its ``done`` flag (item-level resume)."""
        rel = posixpath.join(self.stage_rel(sequence, stage), "items", f"{index:06d}.json")
        self.root.write_json(rel, record)

    def read_item_record(self, sequence: str, stage: str, index: int) -> dict[str, Any] | None:
        return self.root.read_json(
            posixpath.join(self.stage_rel(sequence, stage), "items", f"{index:06d}.json")
        )

    def create_arrays(self, sequence: str, stage: str, n_items: int, max_points: int, omit=()) -> StageArrays:
        rel = posixpath.join(self.stage_rel(sequence, stage), "arrays.zarr")
        return StageArrays.create(self.root, rel, CONTRACTS[stage], n_items, max_points, omit)

    def arrays(self, sequence: str, stage: str, read_only: bool = True) -> StageArrays:
        rel = posixpath.join(self.stage_rel(sequence, stage), "arrays.zarr")
        return StageArrays.open(self.root, rel, CONTRACTS[stage], read_only=read_only)

    def write_table(self, sequence: str, stage: str, table: str, rows: list[dict[str, Any]]) -> str:
        spec = CONTRACTS[stage].table(table)
        return write_partition(self.root, spec, {"sequence": sequence}, to_table(spec, rows))

    def read_table(self, sequence: str, stage: str, table: str):
        """One sequence's partition of a stage's table (a pyarrow Table)."""
        return read_partition(self.root, CONTRACTS[stage].table(table), {"sequence": sequence})

    def clear_stage(self, sequence: str, stage: str) -> None:
        """Remove a stage's outputs. The manifest goes first, so a reader never sees "done" over
        missing data; the lock file stays."""
        base = self.stage_rel(sequence, stage)
        self.root.remove(posixpath.join(base, "manifest.json"))
        for spec in CONTRACTS[stage].tables:
            remove_partition(self.root, spec, {"sequence": sequence})
        self.root.remove(posixpath.join(base, "blocks"), recursive=True)
        self.root.remove(posixpath.join(base, "items"), recursive=True)
        self.root.remove(posixpath.join(base, "arrays.zarr"), recursive=True)
