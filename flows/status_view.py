"""What ``dsnet status`` shows of a run store: each (sequence, stage)'s state, the report tables,
the bytes each stage stores, and whether the log still has the frames the run ingested.

States: ``done``, ``damaged``, ``stale`` (an upstream stage or the config changed, or the log has
frames the run has not, or lost some), ``running`` (unfinished, its lock held by a live run),
``interrupted`` (unfinished, nobody holds its lock: a killed or stopped run), ``failed``,
``missing``. Unfinished stages say how many of their blocks are done; ``dsnet label`` on the same
run resumes them from there.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from dataclasses import dataclass, field

from dsnet_core.errors import DsnetError
from storage.errors import StoreError
from storage.locks import is_stale
from storage.manifest import Manifest
from storage.run import DASHBOARD, RunStore
from tasks.ingest import IngestStage
from tasks.pipeline import Pipeline
from tasks.run_config import RunConfig, read_run
from tasks.runner import stage_state


def size(n: float) -> str:
    """Bytes as ``812 B``, ``4.1 kB``, ``16.3 MB``, ``2.05 GB`` (powers of 1000)."""
    for unit, div in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n >= div:
            return f"{n / div:.3g} {unit}" if n < 100 * div else f"{n / div:.0f} {unit}"
    return f"{n:.0f} B"


@dataclass
class LogChange:
    """A sequence whose log frames differ from the frames the run ingested."""

    log: int
    run: int
    new: int
    gone: int


@dataclass
class StatusView:
    store: RunStore
    run: RunConfig
    pipeline: Pipeline
    verify: bool = False
    damaged: list = field(default_factory=list)
    changes: dict[str, LogChange] = field(default_factory=dict)
    unfinished: int = 0
    log_note: str | None = None
    stage_total: dict[str, int] = field(default_factory=dict)
    frames: int = 0
    _reader: object = None

    @classmethod
    def open(cls, root: str, verify: bool = False) -> StatusView:
        """Raises StoreError: no run store at ``root`` (or a file)."""
        store = RunStore(root)
        run = read_run(store)
        return cls(store, run, run.pipeline(), verify)

    @property
    def ingest(self) -> IngestStage:
        """The method's ingest stage (its frame table is the run's list of frames)."""
        return next(s for s in self.pipeline if isinstance(s, IngestStage))

    def sequences(self) -> list[str]:
        return sorted(set(self.store.sequences()) | set(self.run.sequences))

    def rows(self, verbose: bool = False) -> Iterator[list[str]]:
        """One table row per (sequence, stage)."""
        for seq in self.sequences():
            change = self._log_change(seq)
            ingest = self.store.read_manifest(seq, self.ingest.name)
            n_frames = ingest.n_items if ingest is not None and ingest.status == "done" else 0
            self.frames += n_frames
            for stage in self.pipeline.names():
                state, m, n_done = stage_state(
                    self.store, self.pipeline, seq, stage, self.run, full=self.verify
                )
                if state == "damaged":
                    found = self.store.check_stage(seq, self.pipeline[stage].contract, m, full=self.verify)
                    for d in found if self.verify else ():  # for the rerun that repairs it
                        self.store.note_found(d.where, d.problem)
                    self.damaged += found
                row = [
                    seq,
                    stage,
                    self._state(seq, stage, state, m, n_done, change),
                    "" if m is None else f"{n_done}/{len(m.blocks)}",
                    "" if m is None else str(m.n_items),
                    "" if m is None else m.fingerprint,
                    "" if m is None or not m.timings else f"{m.timings.get('wall_s', 0):.2f}",
                ]
                if verbose:
                    row += self._bytes(seq, stage, n_frames)
                yield row

    def _state(
        self, seq: str, stage: str, state: str, m: Manifest | None, n_done: int, change: LogChange | None
    ) -> str:
        if state == "partial":
            self.unfinished += 1
            if m.status == "failed":
                return "failed"
            if self._lock_live(seq, stage):
                return "running"
            return "interrupted (all blocks done, not finished)" if n_done == len(m.blocks) else "interrupted"
        if change is not None and state in ("done", "damaged"):
            return "stale (log changed)"
        return state

    def _lock_live(self, seq: str, stage: str) -> bool:
        holder = self.store.root.read_json(self.store.lock_rel(seq, stage))
        return bool(holder) and not is_stale(holder, self.run.options.stale_after_s)

    def _bytes(self, seq: str, stage: str, n_frames: int) -> list[str]:
        n = sum(self.store.stage_bytes(seq, self.pipeline[stage].contract).values())
        self.stage_total[stage] = self.stage_total.get(stage, 0) + n
        return [size(n), size(n / n_frames) if n_frames and n else ""]

    def _log_change(self, seq: str) -> LogChange | None:
        """The log's frames of ``seq`` against ingest's frame table (None: the same, or not known)."""
        m = self.store.read_manifest(seq, self.ingest.name)
        if m is None or m.status != "done" or self.log_note is not None:
            return None
        try:
            self._reader = self._reader or self.run.open_log()
            in_log = [f.frame_id for f in self._reader.frames(seq)]
        except (DsnetError, OSError, ValueError) as exc:  # status still shows the store
            self.log_note = f"the log {self.run.data} does not open ({exc}): not compared with the run"
            return None
        try:
            in_run = [
                str(f)
                for f in self.store.read_table(seq, self.ingest.table("frames"))["frame_id"].to_pylist()
            ]
        except StoreError:  # a damaged frame table: ingest's row says so
            return None
        if in_log == in_run:
            return None
        change = LogChange(
            len(in_log), len(in_run), len(set(in_log) - set(in_run)), len(set(in_run) - set(in_log))
        )
        self.changes[seq] = change
        return change

    def report_rows(self, verbose: bool = False) -> list[list[str]]:
        """One row per report table the run wrote (``done``/``damaged``, sequence ``(run)``); a
        refine table left by an earlier run with refine on, where this run has it off, says so
        (``from an earlier run (refine is off)``) and is not checked."""
        from flows.report.tables import REPORT_TABLES

        refine_on = "refine" in self.pipeline.names()
        rows = []
        for name, spec in REPORT_TABLES.items():
            if not self.store.has_table(spec):
                continue
            if name.startswith("refine_") and not refine_on:
                state = "from an earlier run (refine is off)"
            else:
                found = self.store.check_run_table(spec, full=self.verify)
                self.damaged += found
                state = "damaged" if found else "done"
            row = ["(run)", f"table {name}", state, "", "", "", ""]
            if verbose:
                n = sum(self.store.root.sizes(f"tables/{name}").values())
                self.stage_total["(report)"] = self.stage_total.get("(report)", 0) + n
                row += [size(n), ""]
            rows.append(row)
        return rows

    def dashboard_row(self, verbose: bool = False) -> list[list[str]]:
        """The run's dashboard page, where written."""
        n = self.store.root.size(DASHBOARD)
        if n is None:
            return []
        if verbose:
            self.stage_total["(report)"] = self.stage_total.get("(report)", 0) + n
        return [["(run)", "dashboard.html", "done", "", "", "", "", *([size(n), ""] if verbose else [])]]

    def notes(self, verbose: bool = False) -> list[str]:
        """The lines under the table: damage, log changes, how to resume, the store's size."""
        out = [f"damaged: {d.where}: {d.problem}" for d in self.damaged[:20]]
        if self.damaged:
            out.append(f"{len(self.damaged)} damaged files: `dsnet label` on this store recomputes them")
        for seq, c in self.changes.items():
            out.append(
                f"stale: sequence {seq}: the log has {c.log} frames, the run {c.run} ({c.new} new, {c.gone} "
                f"gone): `dsnet label` on this store labels it again"
            )
        if self.log_note:
            out.append(self.log_note)
        if self.unfinished:
            out.append(
                "unfinished stages: `dsnet label` with the same --run resumes them from their finished blocks"
            )
        if verbose and self.stage_total:
            out += self._usage()
        return out

    def _usage(self) -> list[str]:
        total = sum(self.stage_total.values())
        per = f", {size(total / self.frames)} per frame over {self.frames} frames" if self.frames else ""
        lines = [f"store: {size(total)}{per}"]
        lines += [
            f"  {stage}: {size(n)} ({100 * n / total:.0f} %)"
            for stage, n in sorted(self.stage_total.items(), key=lambda kv: -kv[1])
            if n
        ]
        scans = self._scan_bytes()
        if scans:
            lines.append(f"the log's scans: {size(scans)}; the store is {total / scans:.2f}× that")
        return lines

    def _scan_bytes(self) -> int:
        """Bytes of the distinct local source files ingest recorded (0 when none is local)."""
        ingest = self.ingest
        paths: set[str] = set()
        for seq in self.sequences():
            m = self.store.read_manifest(seq, ingest.name)
            if m is not None and m.status == "done":
                paths.update(
                    str(p)
                    for p in self.store.read_table(seq, ingest.table("frames"))["source_path"].to_pylist()
                )
        return sum(os.path.getsize(p) for p in paths if p and os.path.isfile(p))
