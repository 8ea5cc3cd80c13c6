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

Integrity: each item's record (and its block's fragment) holds the sizes and digests of the
item's chunks, the manifest those of the stage's table partitions; :meth:`RunStore.check_stage`
compares a finished stage's files with them (cheap: one listing of the arrays and one size per
table; ``full``: every chunk decoded and hashed) and returns what is damaged.
"""

from __future__ import annotations

import logging
import os
import posixpath
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from storage.arrays import StageArrays, digest
from storage.contract import StageContract, TableSpec
from storage.errors import DamagedStoreError, NoRunConfigError, StoreError, StoreFormatError
from storage.fs import RootFS
from storage.manifest import BlockFragment, Manifest
from storage.names import check_plain_name
from storage.tables import (
    PART,
    decode,
    encode,
    footer_ok,
    partition_rel,
    put_file,
    read_partition,
    read_table,
    remove_partition,
    to_table,
)

DASHBOARD = "dashboard.html"
STORE_FORMAT = 1
"""The run store's format version, recorded in every run config (``store_format``). A store written
in another format is refused with one line that says to relabel: the product carries no readers
of formats from before its release."""
BLOCK_RECORD = ".b2"
ROWS_SUFFIX = ".rows"
DAMAGE_NOTE = "damage.json"
"""A finished stage's note of damage a reader found (:meth:`RunStore.note_damage`)."""

log = logging.getLogger(__name__)
"""A block fragment's table rows beside it: ``blocks/NNNNN.rows`` (not a ``.json``, so not taken
for a fragment)."""
CHANGED = "file does not match the checksum recorded when it was written"


@dataclass(frozen=True)
class Damage:
    """One damaged file of a finished stage.

    Attributes:
        where: the file's URL.
        problem: what is wrong with it.
        item: the item it belongs to (recompute that item), or None.
        block: the block whose fragment is missing (rerun that block), or None.
        table: the table partition it is (rewrite it from the fragments), or None.
        whole: the stage cannot be repaired item by item (its arrays do not open): run it fresh.
    """

    where: str
    problem: str
    item: int | None = None
    block: int | None = None
    table: str | None = None
    whole: bool = False

    def error(self) -> DamagedStoreError:
        return DamagedStoreError(self.where, self.problem)


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
        record = {**config, "run_id": run_id, "store_format": STORE_FORMAT}
        self.root.write_json("run.json", record)
        self.root.write_json(f"runs/{run_id}.json", record)

    def read_run_config(self, run_id: str | None = None) -> dict[str, Any]:
        """The latest run's config, or that of ``run_id``.

        Raises:
            NoRunConfigError: no run config there (or the root is a file).
            StoreFormatError: one of another store format (:data:`STORE_FORMAT`).
        """
        if self.root.local and os.path.isfile(self.root.root):
            raise NoRunConfigError(
                self.root.root, "is a file, not a run folder (the folder `dsnet label --run` wrote)"
            )
        rel = "run.json" if run_id is None else f"runs/{run_id}.json"
        cfg = self.root.read_json(rel)
        if cfg is None:
            raise NoRunConfigError(self.root.url(rel), "no run config here (not a run store, or unknown run)")
        if not isinstance(cfg, dict):
            raise StoreFormatError(self.root.url(rel), "not a run config (expected a JSON object)")
        found = cfg.get("store_format")
        if found != STORE_FORMAT:
            raise StoreFormatError(
                self.root.url(rel),
                f"a run store of format {found or 'before 1'}, this dsnet reads format {STORE_FORMAT}: "
                "relabel the log into a new --run folder",
            )
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
        if manifest.status == "done":  # finished (or repaired): what a reader noted is recomputed
            self._clear_noted(manifest.sequence, manifest.stage, list(manifest.tables))

    # -- damage readers found (a flipped bit keeps a file's size: the cheap check cannot see it) --
    def damage_note_rel(self, sequence: str) -> str:
        return posixpath.join("sequences", check_plain_name(sequence), DAMAGE_NOTE)

    def note_found(self, where: str, problem: str) -> None:
        """Record that a reader (``export``, ``status --verify``) found the file at URL ``where``
        damaged, e.g. a chunk or parquet partition whose bytes no longer match their digest at the
        recorded size. The next run's check of the stage that owns it then decodes and compares
        everything (``full``) and repairs what it finds; the note goes when that stage is done
        again. Best effort: a store that cannot be written (a read-only export) keeps no note."""
        sequence = self._sequence_of(where)
        if sequence is None:
            return
        rel = self.damage_note_rel(sequence)
        try:
            noted = self._noted_entries(sequence) or []
            if not any(n.get("where") == where for n in noted):
                self.root.write_json(rel, [*noted, {"where": where, "problem": problem}])
        except (OSError, StoreError, ValueError) as exc:
            log.warning("could not note the damage of %s: %s", where, exc)

    def _sequence_of(self, where: str) -> str | None:
        """The sequence of a stage file's or table partition's URL (None: a run-level file)."""
        for base in ("sequences", "tables"):
            prefix = self.root.url(base).rstrip("/") + "/"
            if where.startswith(prefix):
                parts = where[len(prefix) :].split("/")
                if base == "sequences" and len(parts) >= 3:
                    return parts[0]
                if base == "tables" and len(parts) >= 3 and parts[1].startswith("sequence="):
                    return parts[1][len("sequence=") :]
        return None

    def _owned(self, sequence: str, stage: str, tables: list[str]) -> tuple[str, ...]:
        """URL prefixes of a stage's files: its folder and its tables' partitions of ``sequence``."""
        stage_url = self.root.url(self.stage_rel(sequence, stage)).rstrip("/") + "/"
        parts = [self.root.url(posixpath.join("tables", t, f"sequence={sequence}")) + "/" for t in tables]
        return (stage_url, *parts)

    def _noted_entries(self, sequence: str) -> list[dict] | None:
        """The note's entries ([] without a note; None for a damaged note, as if all were noted)."""
        try:
            noted = self.root.read_json(self.damage_note_rel(sequence))
        except StoreError:
            return None
        if noted is None:
            return []
        return [n for n in noted if isinstance(n, dict)] if isinstance(noted, list) else None

    def _noted(self, sequence: str, stage: str, tables: list[str]) -> bool:
        noted = self._noted_entries(sequence)
        if noted is None:
            return True
        owned = self._owned(sequence, stage, tables)
        return any(str(n.get("where", "")).startswith(owned) for n in noted)

    def _clear_noted(self, sequence: str, stage: str, tables: list[str]) -> None:
        rel = self.damage_note_rel(sequence)
        if not self.root.exists(rel):
            return
        owned = self._owned(sequence, stage, tables)
        kept = [
            n for n in self._noted_entries(sequence) or [] if not str(n.get("where", "")).startswith(owned)
        ]
        if kept:
            self.root.write_json(rel, kept)
        else:
            self.root.remove(rel)

    def fragment_rel(self, sequence: str, stage: str, block: int) -> str:
        return posixpath.join(self.stage_rel(sequence, stage), "blocks", f"{block:05d}.json")

    def write_fragment(self, sequence: str, stage: str, fragment: BlockFragment) -> None:
        """The block's rows file (when it has rows), then its fragment: the fragment commits both."""
        rel = self.fragment_rel(sequence, stage, fragment.block)
        if fragment.rows:
            rows = fragment.model_dump_json(include={"rows"}).encode()
            self.root.write_bytes(rel[: -len(".json")] + ROWS_SUFFIX, rows)
            fragment = fragment.model_copy(update={"rows": {}, "rows_bytes": len(rows)})
        self.root.write_bytes(rel, fragment.model_dump_json().encode())

    def remove_fragment(self, sequence: str, stage: str, block: int) -> None:
        """Forget a finished block (a resume reruns it)."""
        self.root.remove(self.fragment_rel(sequence, stage, block))

    def fragments(
        self, sequence: str, stage: str, fingerprint: str, rows: bool = False
    ) -> dict[int, BlockFragment]:
        """Finished blocks of the stage with this fingerprint; ``rows``: with their table rows.

        A fragment whose rows file is missing or has another size than recorded is not finished
        (its block runs again; :meth:`check_stage` names the file)."""
        return self._fragments(sequence, stage, fingerprint, rows)[0]

    def _fragments(
        self, sequence: str, stage: str, fingerprint: str, rows: bool
    ) -> tuple[dict[int, BlockFragment], list[Damage]]:
        base = posixpath.join(self.stage_rel(sequence, stage), "blocks")
        sizes = self.root.sizes(base)
        out, bad = {}, []
        for name in sorted(sizes):
            if not name.endswith(".json") or name.startswith(".") or "/" in name:
                continue
            data = self.root.read_json(posixpath.join(base, name))
            if data is None:
                continue
            frag = BlockFragment.model_validate(data)
            if frag.fingerprint != fingerprint:
                continue
            if frag.rows_bytes:
                rows_rel = posixpath.join(base, name[: -len(".json")] + ROWS_SUFFIX)
                found = sizes.get(rows_rel[len(base) + 1 :])
                if found != frag.rows_bytes:
                    now = "is missing" if found is None else f"has {found} bytes"
                    problem = f"block rows file {now}, {frag.rows_bytes} when written"
                    bad.append(Damage(self.root.url(rows_rel), problem, block=frag.block))
                    continue
                if rows:
                    frag.rows = (self.root.read_json(rows_rel) or {}).get("rows", {})
            out[frag.block] = frag
        return out, bad

    def completed_blocks(self, sequence: str, stage: str, fingerprint: str) -> set[int]:
        return set(self.fragments(sequence, stage, fingerprint))

    def block_bytes_rel(self, sequence: str, stage: str, name: str) -> str:
        return posixpath.join(self.stage_rel(sequence, stage), "blocks", name)

    def write_block_bytes(self, sequence: str, stage: str, name: str, data: bytes) -> None:
        """A block's own output beside its fragment (written before the fragment), then its
        record ``<name>.b2`` (size and digest; not a ``.json``, so not taken for a fragment)."""
        rel = self.block_bytes_rel(sequence, stage, name)
        self.root.write_bytes(rel, data)
        self.root.write_json(rel + BLOCK_RECORD, {"size": len(data), "blake2b": digest(data)})

    def read_block_bytes(self, sequence: str, stage: str, name: str) -> bytes:
        """Raises StoreError when missing, DamagedStoreError when it differs from its record."""
        rel = self.block_bytes_rel(sequence, stage, name)
        data = self.root.read_bytes(rel)
        record = self.root.read_json(rel + BLOCK_RECORD)
        if data is None and record is None:
            raise StoreError(self.root.url(rel), "block output missing")
        if data is None:
            raise DamagedStoreError(self.root.url(rel), "block output is missing", self._fresh_fix(stage))
        if record is None:  # written right after the output, before the block's fragment
            raise DamagedStoreError(self.root.url(rel), "block output has no record", self._fresh_fix(stage))
        if digest(data) != record["blake2b"]:
            problem = f"block output ({len(data)} bytes) does not match the record written with it"
            raise DamagedStoreError(self.root.url(rel), problem, self._fresh_fix(stage))
        return data

    @staticmethod
    def _fresh_fix(stage: str) -> str:
        return f"rerun `dsnet label` on it to recompute stage {stage!r}"

    def item_record_rel(self, sequence: str, stage: str, index: int) -> str:
        return posixpath.join(self.stage_rel(sequence, stage), "items", f"{index:06d}.json")

    def write_item_record(self, sequence: str, stage: str, index: int, record: dict[str, Any]) -> None:
        """One item's table rows, counts and chunk record, written before its ``done`` flag
        (item-level resume and integrity checks)."""
        self.root.write_json(self.item_record_rel(sequence, stage, index), record, compact=True)

    def read_item_record(self, sequence: str, stage: str, index: int) -> dict[str, Any] | None:
        return self.root.read_json(self.item_record_rel(sequence, stage, index))

    def remove_item_record(self, sequence: str, stage: str, index: int) -> None:
        """Forget a written item (a resume recomputes it)."""
        self.root.remove(self.item_record_rel(sequence, stage, index))

    def read_stage_state(self, sequence: str, stage: str) -> dict[str, Any] | None:
        """A sequential stage's saved resume state, or None."""
        return self.root.read_json(posixpath.join(self.stage_rel(sequence, stage), "state.json"))

    def write_stage_state(self, sequence: str, stage: str, state: dict[str, Any] | None) -> None:
        """Save (or, with None, remove) a sequential stage's resume state."""
        rel = posixpath.join(self.stage_rel(sequence, stage), "state.json")
        if state is None:
            self.root.remove(rel)
        else:
            self.root.write_json(rel, state, compact=True)

    def _records(self, sequence: str, stage: str):
        return lambda index: self.read_item_record(sequence, stage, index)

    def create_arrays(
        self, sequence: str, contract: StageContract, n_items: int, max_points: int, omit=(), dims=None
    ) -> StageArrays:
        rel = posixpath.join(self.stage_rel(sequence, contract.stage), "arrays.zarr")
        records = self._records(sequence, contract.stage)
        return StageArrays.create(self.root, rel, contract, n_items, max_points, omit, dims, records)

    def arrays(self, sequence: str, contract: StageContract, read_only: bool = True) -> StageArrays:
        """A stage's arrays; reads check each item against its record (see :mod:`storage.arrays`)."""
        rel = posixpath.join(self.stage_rel(sequence, contract.stage), "arrays.zarr")
        records = self._records(sequence, contract.stage)
        return StageArrays.open(self.root, rel, contract, read_only=read_only, records=records)

    def write_table(self, sequence: str, spec: TableSpec, rows: list[dict[str, Any]]) -> dict[str, Any]:
        """Write one sequence's partition. Returns its record for the manifest: ``path`` (relative
        to the root), ``size`` and ``blake2b`` of the file."""
        rel = posixpath.join(partition_rel(spec, {"sequence": sequence}), PART)
        data = encode(spec, to_table(spec, rows))
        put_file(self.root, rel, data)
        return {"path": rel, "size": len(data), "blake2b": digest(data)}

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

    def stage_bytes(self, sequence: str, contract: StageContract) -> dict[str, int]:
        """Bytes a (sequence, stage) occupies: ``arrays`` (its zarr group), ``records`` (block
        fragments, item records, block bytes, manifest, state) and ``tables`` (its partitions of its
        tables). One listing of the stage folder and one per table partition."""
        out = {"arrays": 0, "records": 0, "tables": 0}
        for rel, size in self.root.sizes(self.stage_rel(sequence, contract.stage)).items():
            out["arrays" if rel.startswith("arrays.zarr/") else "records"] += size
        for spec in contract.tables:
            rel = partition_rel(spec, {"sequence": sequence})
            out["tables"] += sum(self.root.sizes(rel).values())
        return out

    # -- integrity -------------------------------------------------------------------------------
    def check_stage(
        self,
        sequence: str,
        contract: StageContract,
        manifest: Manifest,
        full: bool = False,
        flags: bool = False,
    ) -> list[Damage]:
        """What is damaged in a finished stage's files (empty: nothing found).

        Cheap (default): every block fragment is there; every recorded item's chunk files exist
        with their recorded sizes (one listing of the arrays folder), its ``done`` and
        ``n_points`` chunks exist and its item record is there; an item whose ``done`` chunk exists
        but which has no record (in its fragment or its own file) is damaged; every table partition
        has its recorded size (a table without a record in the manifest is damaged). ``full`` also
        decodes every recorded item and compares digests, and hashes every table partition.
        ``flags`` (what a run checks before it skips a stage) also decodes every item's 1-byte
        ``done`` chunk: a flipped bit keeps its size.
        """
        if not full and self._noted(sequence, contract.stage, [t.name for t in contract.tables]):
            full = True  # a reader found damage the cheap check cannot see: look at every byte
        frags, out = self._fragments(sequence, contract.stage, manifest.fingerprint, rows=False)
        for b in range(len(manifest.blocks)):
            if b not in frags and not any(d.block == b for d in out):
                where = self.root.url(self.fragment_rel(sequence, contract.stage, b))
                out.append(Damage(where, "block fragment is missing", block=b))
        out += self._check_block_bytes(sequence, contract.stage)
        if contract.arrays and manifest.n_items:
            out += self._check_arrays(sequence, contract, frags, full, flags)
        for spec in contract.tables:
            out += self._check_table(sequence, spec, manifest.tables.get(spec.name), full)
        return out

    def _check_block_bytes(self, sequence: str, stage: str) -> list[Damage]:
        """Blocks' own outputs against their records: any damage makes the stage run fresh (the
        store does not know which block wrote which output)."""
        base = posixpath.join(self.stage_rel(sequence, stage), "blocks")
        sizes = self.root.sizes(base)
        out = []
        for name in sorted(sizes):
            if name.endswith(BLOCK_RECORD) and "/" not in name:
                record = self.root.read_json(posixpath.join(base, name)) or {}
                data = name[: -len(BLOCK_RECORD)]
                found = sizes.get(data)
                if found != record.get("size"):
                    now = "is missing" if found is None else f"has {found} bytes"
                    problem = f"block output {now}, {record.get('size')} when written"
                    out.append(Damage(self.root.url(posixpath.join(base, data)), problem, whole=True))
        return out

    def _check_arrays(
        self,
        sequence: str,
        contract: StageContract,
        frags: dict[int, BlockFragment],
        full: bool,
        flags: bool = False,
    ) -> list[Damage]:
        rel = posixpath.join(self.stage_rel(sequence, contract.stage), "arrays.zarr")
        try:
            arrays = self.arrays(sequence, contract)
        except StoreError as exc:
            return [Damage(self.root.url(rel), f"arrays cannot be opened ({exc.problem})", whole=True)]
        sizes = self.root.sizes(rel)
        items_rel = posixpath.join(self.stage_rel(sequence, contract.stage), "items")
        item_files = self.root.sizes(items_rel)
        declared = {s.name for s in contract.arrays}  # a reader's contract may declare fewer arrays
        out: list[Damage] = []
        for frag in frags.values():
            for item in sorted(set(frag.items) - set(frag.records)):
                if sizes.get(arrays.chunk_rel("done", item)) is not None:  # written, yet not recorded
                    out.append(
                        Damage(arrays.chunk_url("done", item), f"item {item} is done but not recorded", item)
                    )
            for item, record in sorted(frag.records.items()):
                bad = None
                if record.get("chunks") is None:
                    out.append(
                        Damage(
                            arrays.chunk_url("done", item),
                            f"item {item} is done but its record lists no chunks",
                            item,
                        )
                    )
                    continue
                if f"{item:06d}.json" not in item_files:
                    where = self.root.url(self.item_record_rel(sequence, contract.stage, item))
                    out.append(Damage(where, f"record of item {item} is missing", item))
                    continue
                chunks = record["chunks"]
                expected = {name: c.get("size") for name, c in chunks.items() if name in declared}
                expected["done"] = -1  # must exist
                if record.get("n_points"):
                    expected["n_points"] = -1
                for name, size in expected.items():
                    if name not in arrays._arrays:
                        bad = Damage(f"{arrays.where}/{name}", "array is missing", whole=True)
                        break
                    found = sizes.get(arrays.chunk_rel(name, item))
                    if size is None:
                        continue
                    if found is None:
                        bad = Damage(arrays.chunk_url(name, item), f"chunk of item {item} is missing", item)
                    elif size >= 0 and found != size:
                        problem = f"chunk of item {item} has {found} bytes, {size} when written"
                        bad = Damage(arrays.chunk_url(name, item), problem, item)
                    if bad is not None:
                        break
                if bad is None and full:
                    try:
                        arrays.read_item(item)
                    except StoreError as exc:  # damaged, or "not done": its done flag was overwritten
                        bad = Damage(exc.where, exc.problem, item)
                elif bad is None and flags and (problem := arrays.check_done_flag(item)) is not None:
                    bad = Damage(arrays.chunk_url("done", item), problem, item)
                if bad is not None:
                    out.append(bad)
        return out

    def _check_table(
        self, sequence: str, spec: TableSpec, record: dict[str, Any] | None, full: bool
    ) -> list[Damage]:
        rel = posixpath.join(partition_rel(spec, {"sequence": sequence}), PART)
        if record is None:  # finalize records every table it writes in the manifest
            return [
                Damage(self.root.url(rel), "table partition has no record in the manifest", table=spec.name)
            ]
        return self._check_table_file(rel, spec, record, full)

    def _check_table_file(
        self, rel: str, spec: TableSpec, record: dict[str, Any], full: bool
    ) -> list[Damage]:
        """One parquet file against its record (size and digest); ``full``: its digest and every
        page's checksum too."""
        where = self.root.url(rel)
        if not full:
            size = self.root.size(rel)
            if size == record.get("size"):
                return []
            problem = (
                "file is missing"
                if size is None
                else f"file has {size} bytes, {record.get('size')} when written"
            )
            return [Damage(where, problem, table=spec.name)]
        data = self.root.read_bytes(rel)
        if data is None:
            return [Damage(where, "file is missing", table=spec.name)]
        if digest(data) != record.get("blake2b"):
            return [Damage(where, CHANGED, table=spec.name)]
        if not footer_ok(data):
            return [Damage(where, f"parquet file cannot be read ({len(data)} bytes)", table=spec.name)]
        if full:
            try:
                decode(where, data)
            except DamagedStoreError as exc:
                return [Damage(where, exc.problem, table=spec.name)]
        return []

    # -- whole-run tables ------------------------------------------------------------------------
    def has_table(self, spec: TableSpec) -> bool:
        return self.root.exists(posixpath.join("tables", spec.name))

    def table_url(self, spec: TableSpec) -> str:
        """Where a table lives (for messages)."""
        return self.root.url(posixpath.join("tables", spec.name))

    @staticmethod
    def run_table_rels(spec: TableSpec) -> tuple[str, str]:
        """An unpartitioned table's file and its record (size and digest; hidden, so parquet
        dataset readers and result listings pass it by)."""
        base = posixpath.join("tables", spec.name)
        return posixpath.join(base, PART), posixpath.join(base, "." + PART + BLOCK_RECORD)

    def write_run_table(self, spec: TableSpec, rows: list[dict[str, Any]]) -> str:
        """An unpartitioned table (``tables/<name>/part-0.parquet``), rewritten whole, then its
        record (size and digest: :meth:`check_run_table`)."""
        rel, record = self.run_table_rels(spec)
        data = encode(spec, to_table(spec, rows))
        self.root.remove(record)  # a file without its record is damage: the report rewrites it
        put_file(self.root, rel, data)
        self.root.write_json(record, {"size": len(data), "blake2b": digest(data)})
        return rel

    def remove_run_table(self, spec: TableSpec) -> None:
        """Remove an unpartitioned table (its file first, then its record and folder)."""
        rel, record = self.run_table_rels(spec)
        self.root.remove(rel)
        self.root.remove(record)
        self.root.remove(posixpath.join("tables", spec.name), recursive=True)

    def check_run_table(self, spec: TableSpec, full: bool = False) -> list[Damage]:
        """What is damaged in an unpartitioned (report) table: cheap, its size against its record
        (no record: damaged); ``full``, its digest and every page's checksum."""
        rel, record_rel = self.run_table_rels(spec)
        try:
            record = self.root.read_json(record_rel)
        except StoreError as exc:
            return [Damage(exc.where, exc.problem, table=spec.name)]
        if record is None:
            return [Damage(self.root.url(record_rel), "record of the table is missing", table=spec.name)]
        return self._check_table_file(rel, spec, record, full)

    def read_all(self, spec: TableSpec):
        """A whole table, partition columns included as strings (a pyarrow Table); page checksums
        are verified, and an unpartitioned table's file against its record.

        Raises:
            StoreError: the table was never written.
            DamagedStoreError: a file of it is truncated, lost or changed.
        """
        if not self.has_table(spec):
            raise StoreError(self.table_url(spec), "table not written yet")
        if not spec.partition:
            rel, record_rel = self.run_table_rels(spec)
            record, data = self.root.read_json(record_rel), self.root.read_bytes(rel)
            if record is None or data is None or digest(data) != record.get("blake2b"):
                problem = (
                    "record of the table is missing"
                    if record is None
                    else "file is missing"
                    if data is None
                    else "file does not match the checksum recorded when it was written"
                )
                raise DamagedStoreError(
                    self.root.url(rel), problem, "rerun `dsnet label` on it to rewrite the report"
                )
        return read_table(self.root, spec)

    # -- the dashboard ---------------------------------------------------------------------------
    def write_dashboard(self, page: bytes) -> str:
        """Write ``ROOT/dashboard.html``; returns its location."""
        self.root.write_bytes(DASHBOARD, page)
        return self.root.path(DASHBOARD) if self.root.local else self.root.url(DASHBOARD)
