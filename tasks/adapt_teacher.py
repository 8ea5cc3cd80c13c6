"""The teacher of ``dsnet adapt``: labels the target logs with the method's full pipeline including
``refine`` (one run store per log under ``CKPT/store/``, resumed like any run store: a new teacher
recomputes infer onward only), then selects each round's pseudo-labels from the store
(:mod:`dsnet_core.adapt.selection`) into ``CKPT/rounds/R/pseudo/<log>/sequences/SS/labels/ID.label``.

A round's pseudo-labels are written under a temporary name, renamed into place, and
``CKPT/rounds/R/pseudo.json`` (their key and statistics) written last: a round whose file is there
with the same key (teacher digest, selection settings, logs, excluded frames) is reused as it is.
"""

from __future__ import annotations

import json
import os
import shutil
from collections.abc import Callable, Iterator, Mapping
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from dsnet_core.adapt import (
    ConfidenceHistogram,
    LabelOverlay,
    RoundData,
    SelectionParams,
    SelectionStats,
    TrackVotes,
    VoxelVotes,
    frame_consistency,
    label_file,
    read_labels,
    select_frame,
    to_world,
    volumes,
    write_labels,
)
from dsnet_core.checkpoints import checkpoint_digest
from dsnet_core.io.reader import LogReader
from dsnet_core.labels import LabelMap
from dsnet_core.refine import decode_labels, encode_labels
from storage.run import RunStore
from tasks.methods import LabelSettings, Method
from tasks.pipeline import Pipeline
from tasks.refine import FrameLoader
from tasks.run_config import RunConfig, build_run_config
from tasks.runner import ITEM_LISTENERS, make_context, run_stage_plain

LabelProgress = Callable[[int, str, int, int], None]
"""``(round, what, done, total)``: items of a labelling stage or frames of the selection."""


@dataclass(frozen=True)
class FrameView:
    """One frame as selection reads it (see :func:`~dsnet_core.adapt.selection.select_frame`)."""

    frame_id: str
    sem: np.ndarray
    inst: np.ndarray
    conf: np.ndarray
    frame_sem: np.ndarray
    world: np.ndarray | None
    gt: np.ndarray | None


class TeacherLabeller:
    """``(round, teacher) -> RoundData`` for :class:`~dsnet_core.adapt.trainer.AdaptTrainer`.

    Args:
        out: the adaptation's checkpoint folder.
        logs: the target logs (opened readers, in order).
        method: the labelling method; ``settings`` its settings (the checkpoint is each round's teacher).
        params: the selection settings.
        label_map: the model's class map.
        exclude: ``(sequence, frame_id)`` of frames that have corrections (no pseudo-labels for them).
        progress: called as labelling and selection advance.
        reader_options: the reader options the logs were opened with (recorded in each store's run
            config, so the stages reopen the logs alike; ``dsnet adapt`` opens them with none).
    """

    def __init__(
        self,
        out: Path,
        logs: list[LogReader],
        method: Method,
        settings: LabelSettings,
        params: SelectionParams,
        label_map: LabelMap,
        exclude: set[tuple[str, str]] = frozenset(),
        progress: LabelProgress | None = None,
        reader_options: Mapping[str, Any] | None = None,
    ) -> None:
        self.out, self.logs, self.method, self.settings = Path(out), logs, method, settings
        self.reader_options = dict(reader_options or {})
        self.params, self.label_map, self.exclude, self.progress = params, label_map, set(exclude), progress

    # -- the labeller --------------------------------------------------------------------------
    def __call__(self, r: int, teacher: Path) -> RoundData:
        folder = self.out / "rounds" / str(r)
        key = self._key(teacher)
        marker = folder / "pseudo.json"
        if marker.is_file():
            saved = json.loads(marker.read_text())
            if saved.get("key") == key:
                return self._round(folder, saved["record"])
        stores = [self.label(i, teacher, r) for i in range(len(self.logs))]
        record = {
            "teacher": str(teacher),
            "teacher_digest": key["teacher"],
            **self._select(r, stores, folder),
        }
        tmp = marker.with_name("pseudo.json.tmp")
        tmp.write_text(json.dumps({"key": key, "record": record}, indent=1) + "\n")
        os.replace(tmp, marker)
        return self._round(folder, record)

    def _key(self, teacher: Path) -> dict:
        return {
            "teacher": checkpoint_digest(teacher),
            "selection": asdict(self.params),
            "logs": [str(r.root) for r in self.logs],
            "exclude": sorted(map(list, self.exclude)),
        }

    def _round(self, folder: Path, record: dict) -> RoundData:
        items = []
        for i, reader in enumerate(self.logs):
            overlay = LabelOverlay(reader, folder / "pseudo" / str(i))
            items += volumes(overlay, self.settings.scans or 1, 1.0, "target")
        return RoundData(items, record)

    # -- labelling through the store -------------------------------------------------------------
    def pipeline(self, teacher: Path) -> tuple[Pipeline, dict]:
        """The method's pipeline with ``refine`` and its stage configs for ``teacher``."""
        settings = self.settings.model_copy(update={"checkpoint": str(teacher), "refine": True})
        stages = self.method.stage_settings(settings)
        pipeline = self.method.pipeline(self.method.options(settings), stages)
        grid = self.method.model_grid(stages)
        if grid is not None:
            stages.setdefault("ingest", {})["grid"] = grid
        return pipeline, stages

    def store(self, i: int) -> RunStore:
        return RunStore(self.out / "store" / f"{i:02d}-{Path(self.logs[i].root).name}")

    def label(self, i: int, teacher: Path, r: int) -> tuple[RunStore, Pipeline, RunConfig]:
        """Label log ``i`` with ``teacher`` up to the refined labels (resuming what the store holds)."""
        reader, store = self.logs[i], self.store(i)
        pipeline, stages = self.pipeline(teacher)
        run_id = f"adapt-round{r}"
        run = build_run_config(
            pipeline,
            str(reader.root),
            reader.format,
            reader_options=self.reader_options,
            sequences=reader.sequences(),
            stages=stages,
            run_id=run_id,
        )
        store.write_run_config(run_id, run.model_dump(mode="json", exclude={"run_id", "store_format"}))
        names = [*pipeline.upstream_closure(pipeline.labels), pipeline.labels]
        total = sum(len(reader.frames(s)) for s in reader.sequences())
        for stage in names:
            counted = [0]

            def item_done(
                _sequence: str, item_stage: str, stage: str = stage, counted: list = counted
            ) -> None:
                if item_stage == stage and self.progress is not None:
                    counted[0] += 1
                    self.progress(r, f"{stage} (log {i + 1}/{len(self.logs)})", counted[0], total)

            ITEM_LISTENERS.append(item_done)
            try:
                for seq in reader.sequences():
                    run_stage_plain(store, pipeline, seq, stage, run, run_id)
            finally:
                ITEM_LISTENERS.remove(item_done)
            if self.progress is not None:
                self.progress(r, f"{stage} (log {i + 1}/{len(self.logs)})", total, total)
        return store, pipeline, run

    # -- selection ---------------------------------------------------------------------------------
    def _select(self, r: int, stores: list, folder: Path) -> dict:
        """Thresholds over every log, then the pseudo-labels of every frame; returns the statistics."""
        hist = ConfidenceHistogram(self.label_map.num_classes)
        consistency = {}
        frames = sum(len(reader.frames(s)) for reader in self.logs for s in reader.sequences())
        for i, (store, pipeline, run) in enumerate(stores):
            for seq in self.logs[i].sequences():
                votes, tracks = self._votes(store, pipeline, run, seq)
                consistency[i, seq] = (votes, tracks)
                for f in self._frames(store, pipeline, run, seq):
                    hist.add(
                        f.sem, f.conf, frame_consistency(f.sem, f.inst, f.world, votes, tracks, self.params)
                    )
        thresholds = hist.thresholds(self.params)
        stats = SelectionStats(self.label_map.num_classes)
        tmp = folder / "pseudo.tmp"
        shutil.rmtree(tmp, ignore_errors=True)
        done = 0
        for i, (store, pipeline, run) in enumerate(stores):
            for seq in self.logs[i].sequences():
                votes, tracks = consistency[i, seq]
                for f in self._frames(store, pipeline, run, seq):
                    done += 1
                    if self.progress is not None:
                        self.progress(r, "select pseudo-labels", done, frames)
                    if (seq, f.frame_id) in self.exclude:  # corrected: true labels instead
                        continue
                    ok = frame_consistency(f.sem, f.inst, f.world, votes, tracks, self.params)
                    sem, inst = select_frame(f.sem, f.inst, f.conf, ok, thresholds, self.params)
                    prev = self._previous(r, i, seq, f.frame_id, f.sem.size)
                    stats.add(f.sem, f.inst, f.conf, ok, sem, inst, f.gt, prev)
                    if (sem > 0).any():  # else nothing to learn from: not a training frame
                        path = label_file(tmp / str(i), seq, f.frame_id)
                        write_labels(path, encode_labels(sem, inst, self.label_map))
        shutil.rmtree(folder / "pseudo", ignore_errors=True)
        tmp.mkdir(parents=True, exist_ok=True)
        os.replace(tmp, folder / "pseudo")
        return stats.record(self.label_map.class_names, thresholds)

    def _previous(self, r: int, i: int, seq: str, frame_id: str, n: int) -> np.ndarray | None:
        path = label_file(self.out / "rounds" / str(r - 1) / "pseudo" / str(i), seq, frame_id)
        if r == 1 or not path.is_file():
            return None
        return decode_labels(read_labels(path, n), self.label_map)[0]

    def _votes(self, store, pipeline, run, seq) -> tuple[VoxelVotes | None, tuple]:
        votes, tracks = VoxelVotes(self.label_map.num_classes, self.params.voxel), TrackVotes()
        posed = True
        for f in self._frames(store, pipeline, run, seq):
            tracks.add(f.inst, f.sem, f.frame_sem)
            if f.world is None:
                posed = False
            else:
                free = f.inst == 0
                votes.add(f.world[free], f.frame_sem[free])
        votes.finish()
        return (votes if posed else None), tracks.consistent(self.params)

    def _frames(self, store: RunStore, pipeline: Pipeline, run: RunConfig, seq: str) -> Iterator[FrameView]:
        """The refined frames of a sequence, with the teacher's per-frame labels and confidences."""
        labels = pipeline.labels
        ctx = make_context(store, pipeline, seq, labels, run)
        plan = store.read_manifest(seq, labels).plan
        load = FrameLoader(ctx, labels, plan.get("probs"), plan.get("align"))
        frame_stage = ctx.arrays(pipeline[labels].upstream[0])
        refs = ctx.reader.frames(seq)
        gt_map = ctx.reader.label_map
        scorable = gt_map is not None and tuple(gt_map.class_names) == tuple(self.label_map.class_names)
        for index in np.flatnonzero(ctx.arrays(labels).done()).tolist():
            fi = load(index)
            frame_sem = decode_labels(frame_stage.read_item(index, ["label"])["label"], self.label_map)[0]
            conf = (
                fi.probs[np.arange(fi.sem.size), fi.sem]
                if fi.probs is not None
                else np.zeros(fi.sem.size, np.uint8)
            )
            gt = ctx.reader.labels(refs[index]) if scorable else None
            yield FrameView(
                frame_id=refs[index].frame_id,
                sem=fi.sem,
                inst=fi.inst,
                conf=conf,
                frame_sem=frame_sem,
                world=None if fi.pose is None else to_world(fi.xyz, fi.pose),
                gt=None if gt is None else gt_map.to_train(gt & 0xFFFF).astype(np.int64),
            )
