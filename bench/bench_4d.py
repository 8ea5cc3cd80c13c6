"""4D volumes + stitching vs single-scan clustering + the tracking baseline, one script with two
modes (``bench/bench_4d.py MODE [options]``):

    oracle  on oracle inputs (ground-truth semantics, noisy ground-truth centres): the method alone
    model   on a trained model through the real label flow: the same rows, the product's numbers

Without a mode it runs both in turn with their defaults (model into a new temporary ``--out``).
``bench/bench_4d.py MODE --help`` prints that mode's description and options (kept below as
``ORACLE_DOC`` and ``MODEL_DOC``).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _store4d import SplitStats, poses, stitched, volume_splits, volumes

from dsnet_core.io.semantickitti import SemanticKittiReader
from dsnet_core.labels import load_label_map
from dsnet_core.metrics import PanopticEvaluator
from dsnet_core.metrics.switches import SwitchCounter
from dsnet_core.oracle.labelling import oracle_volumes, stitch_sequence, track_sequence
from dsnet_core.synth import generate_log
from dsnet_core.temporal.tracking import Tracker
from storage.run import RunStore

ORACLE_DOC = """4D volumes + stitching vs single-scan clustering + the tracking baseline, on oracle inputs.

Ground-truth semantics and noisy ground-truth centres (``dsnet_core.oracle.inputs`` noise model) over
synthetic sequences with moving objects; the same BFS clusterer and fusion for every row:

- ``k=1 + tracking``: per scan → cluster → fuse → ego-compensated constant-velocity tracker;
- ``k=1 (no ids across frames)``: the same without tracking (every frame fresh ids), a floor;
- ``k=2/3/4``: k-scan volumes (stride k-1, one shared frame) → cluster → fuse → stitch.

Prints LSTQ, S_assoc, S_cls (``corrected`` mode), PQ and identity switches along ground-truth
tubes over all sequences, and the time per frame of the instance stage, of stitching and of
tracking (the speed ratio stitching/frame is the number to watch, not absolute times).

Run: ``.venv/bin/python bench/bench_4d.py oracle [--frames 40] [--seeds 0 1 2] [--sensor vlp32]``.
"""

MODEL_DOC = """4D volumes + stitching vs single-scan DS-Net + the tracking baseline, on a trained model.

The model-driven counterpart of the ``oracle`` mode ("4D vs the tracking baseline on
the same model and sequences"). Every row goes through the real label flow
(``run_label``: ingest → align → infer → shift → fuse → stitch → score, Prefect included),
one run store per k under ``--out`` (kept, so ``dsnet dashboard`` can be built from them):

- ``k=1 + tracking``: the k = 1 run's per-frame instances (``fuse``'s volume-local ids; with
  k = 1 a volume is one frame) linked by :class:`dsnet_core.temporal.tracking.Tracker` — centroids in
  world coordinates through the pipeline's poses (ego-motion compensation), greedy
  closest-pair association, with and (second row) without the constant-velocity prediction;
- ``k=1 (no ids across frames)``: the k = 1 run's stitched labels. With k = 1 and stride 1
  consecutive volumes share no frame, so the stitcher matches nothing and every frame's
  instances take fresh ids from the sequence counter: a floor for association;
- ``k=2/3/4``: k-scan volumes (stride k − 1, one shared frame) through the model (the
  ``--checkpoint-4d`` model when given), stitched by point IoU on the shared frame.

Scored against the log's ground truth with :class:`PanopticEvaluator` in ``official`` and
``corrected`` mode (LSTQ, S_assoc, S_cls, PQ) and with identity switches along ground-truth tubes
(:mod:`dsnet_core.metrics.switches`). Times: label-flow stage seconds per frame (the sum of the
stages' manifest wall times, ingest..stitch; score excluded), the whole flow call per frame
(one temporary Prefect server serves every run and starts before them; a 1-frame warm-up run
pays for imports, numba compilation and the first Prefect tasks), and stitching or tracking
milliseconds per frame.
With an existing store whose stages are all current, the flow skips them and the stage times are
the ones recorded when they ran (``--force`` recomputes).

Default data: held-out synthetic sequences (seed 303 from sequence 60; the demo model was
trained on seed 101 sequences 0–15 and validated on seed 202 sequences 50–51), hdl64 as trained.

Run: ``OMP_NUM_THREADS=1 .venv/bin/python bench/bench_4d.py model [--checkpoint CKPT]
[--checkpoint-4d CKPT4D] [--sequences 2] [--frames 20] [--scans 1,2,3,4] --out DIR``
(without checkpoints: the bundled ``tiny`` for k = 1 and ``tiny-4d`` for k > 1).
Writes ``DIR/bench_4d_model.json`` and ``DIR/bench_4d_model.md``.
"""


def _parser(mode: str, doc: str) -> argparse.ArgumentParser:
    return argparse.ArgumentParser(
        prog=f"bench_4d.py {mode}", description=doc, formatter_class=argparse.RawDescriptionHelpFormatter
    )


# -- oracle ----------------------------------------------------------------------------------------
LM = load_label_map("semantic-kitti")


def oracle_main(argv: list[str]) -> None:
    ap = _parser("oracle", ORACLE_DOC)
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--sensor", default="vlp32")
    ap.add_argument("--noise", type=float, default=1.0, help="scale of the centre-regression noise")
    args = ap.parse_args(argv)

    rows = ["k=1 + tracking", "k=1 (no ids across frames)", "k=2", "k=3", "k=4"]
    evals = {r: PanopticEvaluator(LM, mode="corrected") for r in rows}
    switches = {r: SwitchCounter(LM) for r in rows}
    times = {r: [0.0, 0.0] for r in rows}  # instance stage, stitch/track
    n_frames = 0
    with tempfile.TemporaryDirectory() as tmp:
        for seed in args.seeds:
            seq = f"{seed:02d}"
            generate_log(
                Path(tmp), sequences=1, frames=args.frames, seed=seed, sensor=args.sensor, first_sequence=seed
            )
            reader = SemanticKittiReader(Path(tmp))
            frames = reader.frames(seq)
            scans = [reader.scan(f) for f in frames]
            gts = [reader.labels(f) for f in frames]
            poses = np.stack([reader.pose(f) for f in frames])
            n_frames += len(frames)
            for row in rows:
                t0 = time.perf_counter()
                k = 1 if row.startswith("k=1") else int(row[2])
                vols = oracle_volumes(scans, gts, poses, LM, k, noise_scale=args.noise)
                t1 = time.perf_counter()
                if row == "k=1 + tracking":
                    preds = track_sequence(vols, scans, poses, LM)
                else:
                    preds = stitch_sequence(vols, LM)
                t2 = time.perf_counter()
                times[row][0] += t1 - t0
                times[row][1] += t2 - t1
                for f, (gt, pred) in enumerate(zip(gts, preds, strict=True)):
                    evals[row].add(gt, pred, frame=f"{f:06d}", sequence=seq)
                    switches[row].add(gt, pred, sequence=seq)
            print(f"sequence {seq}: {len(frames)} frames, {np.mean([len(s) for s in scans]):.0f} points/scan")

    print(
        f"\n{len(args.seeds)} sequences × {args.frames} frames ({args.sensor}), "
        f"noise ×{args.noise}, corrected mode"
    )
    print(
        f"{'method':28s} {'LSTQ':>7s} {'S_assoc':>8s} {'S_cls':>7s} {'PQ':>7s} {'PQ_th':>7s} {'tubes':>6s}"
        f" {'id sw':>6s} {'inst ms/f':>10s} {'ids ms/f':>9s}"
    )
    for row in rows:
        res = evals[row].result()
        t = [1000 * x / n_frames for x in times[row]]
        print(
            f"{row:28s} {res.lstq.lstq:7.4f} {res.lstq.s_assoc:8.4f} {res.lstq.s_cls:7.4f} "
            f"{res.panoptic.pq:7.4f} {res.panoptic.pq_things:7.4f} {res.lstq.n_tubes:6d} "
            f"{switches[row].switches:6d} {t[0]:10.1f} {t[1]:9.2f}"
        )
    print("inst ms/f: align + oracle centres + clustering + fusion; ids ms/f: stitching or tracking")
    print("id sw: identity switches along ground-truth tubes (dsnet_core.metrics.switches)")


# -- model -----------------------------------------------------------------------------------------
FLOW_STAGES = ("ingest", "align", "infer", "shift", "fuse", "stitch")


TRACKING, FLOOR = "k=1 + tracking", "k=1 (no ids across frames)"


TRACKERS = {TRACKING: True, "k=1 + tracking, no velocity": False}  # row -> constant_velocity


def make_log(root: Path, sequences: int, frames: int, seed: int, first: int, sensor: str) -> None:
    """Generate the held-out synthetic log at ``root`` unless the same one is already there."""
    from dsnet_core.synth import generate_log

    stamp = root / "bench_log.json"
    want = {"sequences": sequences, "frames": frames, "seed": seed, "first_sequence": first, "sensor": sensor}
    if stamp.exists() and json.loads(stamp.read_text()) == want:
        return
    t0 = time.perf_counter()
    generate_log(
        root,
        sequences=sequences,
        frames=frames,
        seed=seed,
        sensor=sensor,
        first_sequence=first,
        overwrite=True,
    )
    stamp.write_text(json.dumps(want) + "\n")
    print(
        f"generated {sequences} × {frames} {sensor} frames (seed {seed}) in {time.perf_counter() - t0:.0f} s"
    )


def label_run(data: Path, run: Path, seqs: list[str], k: int, ckpt: str, force: bool) -> dict[str, float]:
    """Run the label flow for one k; seconds of the flow call and of each stage (all sequences)."""
    from flows.commands.label import run_label
    from flows.request import LabelRequest
    from tasks.methods import stage_configs

    stages = stage_configs(scans=k, checkpoint=ckpt)
    t0 = time.perf_counter()
    # stitch at every k (k = 1 defaults to the track stage): the tracking rows are this script's own
    request = LabelRequest(
        data=str(data),
        root=str(run),
        sequences=seqs,
        stages=stages,
        force=force,
        method_options={"temporal": "stitch"},
    )
    summary = run_label(request)
    flow_s = time.perf_counter() - t0
    failed = [r for r in summary if r["action"] == "failed"]
    if failed:
        raise SystemExit(f"label flow failed for k={k}: {failed}")
    store = RunStore(run)
    # a flow that only skipped current stages has no time of its own to report
    ran = any(r["action"] != "skip" for r in summary if r["stage"] in FLOW_STAGES)
    times = {"flow": flow_s if ran else float("nan")}
    for stage in FLOW_STAGES:
        times[stage] = sum(store.read_manifest(s, stage).timings.get("wall_s", 0.0) for s in seqs)
    return times


def checkpoints(ckpt: str | None, ckpt4d: str | None) -> tuple[str, str]:
    """The k = 1 and the k > 1 checkpoint folders (absolute): as given, else the bundled models."""
    from dsnet_core.checkpoints import bundled_checkpoint

    one = ckpt or bundled_checkpoint(1)
    if one is None:
        raise SystemExit("no bundled model in this tree: pass --checkpoint")
    four = ckpt4d or (ckpt if ckpt else bundled_checkpoint(2))
    return str(Path(one).resolve()), str(Path(four).resolve())


def warm_up(root: Path, ckpt: str, sensor: str) -> None:
    """Label a 1-frame log once so that the first timed run does not pay for imports, numba
    compilation, model loading paths and Prefect's first task runs."""
    import shutil

    from dsnet_core.synth import generate_log

    shutil.rmtree(root, ignore_errors=True)
    generate_log(root / "log", sequences=1, frames=1, seed=0, sensor=sensor)
    t0 = time.perf_counter()
    label_run(root / "log", root / "run", ["00"], 1, ckpt, force=True)
    print(f"warm-up label run: {time.perf_counter() - t0:.1f} s")


class Row:
    """Scores and times of one table row, accumulated over sequences."""

    def __init__(self) -> None:
        self.evals = {m: PanopticEvaluator(LM, mode=m, keep_rows=False) for m in ("official", "corrected")}
        self.switches = SwitchCounter(LM)
        self.ids_s = 0.0  # stitching (in memory, re-run on the stored volumes) or tracking
        self.stage_s: dict[str, float] = {}
        self.splits: SplitStats | None = None

    def add(self, seq: str, frame_ids: list[str], gts: list[np.ndarray], preds: list[np.ndarray]) -> None:
        for frame, gt, pred in zip(frame_ids, gts, preds, strict=True):
            for ev in self.evals.values():
                ev.add(gt, pred, frame=frame, sequence=seq)
            self.switches.add(gt, pred, sequence=seq)

    def summary(self, n_frames: int) -> dict:
        out: dict = {}
        for mode, ev in self.evals.items():
            res = ev.result()
            out[mode] = {
                "lstq": res.lstq.lstq,
                "s_assoc": res.lstq.s_assoc,
                "s_cls": res.lstq.s_cls,
                "pq": res.panoptic.pq,
                "pq_things": res.panoptic.pq_things,
                "miou": res.panoptic.miou,
            }
        out["id_switches"] = self.switches.switches
        out["tube_matches"] = self.switches.matches
        if self.stage_s:
            out["label_s_per_frame"] = sum(self.stage_s[s] for s in FLOW_STAGES) / n_frames
            out["flow_s_per_frame"] = self.stage_s["flow"] / n_frames
            out["stage_s_per_frame"] = {s: self.stage_s[s] / n_frames for s in FLOW_STAGES}
        out["ids_ms_per_frame"] = 1000 * self.ids_s / n_frames
        if self.splits is not None:
            out["volume_splits"] = self.splits.rates()
        return out


def _splits(r: dict) -> str:
    if "volume_splits" not in r:
        return "(k=1 run)"
    m, s = r["volume_splits"]["moving"], r["volume_splits"]["static"]
    return " / ".join(f"{x['split']:.0%} of {x['objects']}" if x["objects"] else "-" for x in (m, s))


def markdown(results: dict[str, dict], meta: dict) -> str:
    lines = [
        f"# 4D vs tracking on {meta['checkpoint']}",
        "",
        f"{meta['frames']} frames in {len(meta['sequences'])} sequence(s) ({', '.join(meta['sequences'])}) "
        f"of {meta['data']}; k>1 checkpoint {meta['checkpoint_4d']}.",
        "",
        "| method | LSTQ | S_assoc | S_cls | PQ | LSTQ (corrected) | S_assoc (corr.) | id switches "
        "| label s/frame | flow s/frame | stitch/track ms/frame | split moving / static |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, r in results.items():
        o, c = r["official"], r["corrected"]
        label = f"{r['label_s_per_frame']:.2f}" if "label_s_per_frame" in r else "(k=1 run)"
        flow = f"{r['flow_s_per_frame']:.2f}" if "flow_s_per_frame" in r else "(k=1 run)"
        flow = "(reused)" if flow == "nan" else flow
        lines.append(
            f"| {name} | {o['lstq']:.4f} | {o['s_assoc']:.4f} | {o['s_cls']:.4f} | {o['pq']:.4f} "
            f"| {c['lstq']:.4f} | {c['s_assoc']:.4f} | {r['id_switches']} | {label} | {flow} "
            f"| {r['ids_ms_per_frame']:.1f} | {_splits(r)} |"
        )
    lines += [
        "",
        "LSTQ/S_assoc/S_cls/PQ: official mode unless marked corrected. label s/frame: the stages' "
        "manifest wall times ingest..stitch; flow s/frame: the whole `run_label` call (Prefect "
        "tasks and artifacts included; one server for all runs, started before them); id switches: "
        "along ground-truth tubes (segments ≥ 50 points, IoU > 0.5); stitch/track ms/frame: "
        "dsnet_core's Stitcher re-run in memory on the stored volumes (its output checked equal to "
        "the stored labels) or the Tracker, both without store I/O (the stitch stage's own wall time "
        "is `stage_s_per_frame.stitch` in the JSON); split moving / static: share of ground-truth "
        "objects in a volume (≥ 50 points) that the model cut into ≥ 2 instances (moving: centroid "
        "≥ 0.5 m per frame across the volume's scans).",
    ]
    return "\n".join(lines) + "\n"


def run_all(args, data: Path, reader, seqs, gt, ks, ckpt: str, ckpt4d: str) -> dict[str, Row]:
    """Label the log once per k and score the rows."""
    rows: dict[str, Row] = {}
    for k in ks:
        run = args.out / f"run-k{k}"
        print(f"\n== k = {k}: labelling into {run}")
        times = label_run(data, run, seqs, k, ckpt if k == 1 else ckpt4d, args.force)
        store = RunStore(run)
        name = FLOOR if k == 1 else f"k={k}"
        rows[name] = row = Row()
        row.stage_s, row.splits = times, SplitStats()
        for seq in seqs:
            labels = stitched(store, seq)
            vols = volumes(store, seq)
            t0 = time.perf_counter()
            again = stitch_sequence(vols, LM)
            row.ids_s += time.perf_counter() - t0
            if any(not np.array_equal(a, b) for a, b in zip(labels, again, strict=True)):
                raise SystemExit(
                    f"k={k} {seq}: re-stitching the stored volumes differs from the stored labels"
                )
            row.add(seq, *gt[seq], labels)
            volume_splits(store, seq, LM, row.splits)
            if k == 1:
                scans = [reader.scan(f) for f in reader.frames(seq)]
                for name, cv in TRACKERS.items():
                    track = rows.setdefault(name, Row())
                    t0 = time.perf_counter()
                    preds = track_sequence(vols, scans, poses(store, seq), LM, constant_velocity=cv)
                    track.ids_s += time.perf_counter() - t0
                    track.add(seq, *gt[seq], preds)
        print(f"   k = {k}: flow {times['flow']:.1f} s, stages {sum(times[s] for s in FLOW_STAGES):.1f} s")
    return rows


def model_main(argv: list[str]) -> None:
    ap = _parser("model", MODEL_DOC)
    ap.add_argument("--checkpoint", default=None, help="the k = 1 (3D) model (default: the bundled tiny)")
    ap.add_argument(
        "--checkpoint-4d",
        default=None,
        help="model for k > 1 (default: --checkpoint when given, else the bundled tiny-4d)",
    )
    ap.add_argument("--data", type=Path, default=None, help="SemanticKITTI-layout log with labels and poses")
    ap.add_argument(
        "--sequences",
        default=None,
        help="with --data: comma-separated names (default all); else how many to generate (default 2)",
    )
    ap.add_argument("--frames", type=int, default=20, help="frames per generated sequence (not with --data)")
    ap.add_argument("--sensor", default="hdl64", help="sensor of the generated log and of the warm-up")
    ap.add_argument("--seed", type=int, default=303, help="seed of the generated log (held out)")
    ap.add_argument("--first-sequence", type=int, default=60, help="first generated sequence (held out)")
    ap.add_argument("--scans", default="1,2,3,4", help="values of k; the tracking rows need 1")
    ap.add_argument("--out", type=Path, required=True, help="folder for the run stores and the tables")
    ap.add_argument("--force", action="store_true", help="recompute every stage of existing run stores")
    ap.add_argument("--no-warmup", action="store_true", help="skip the 1-frame warm-up label run")
    args = ap.parse_args(argv)
    ckpt, ckpt4d = checkpoints(args.checkpoint, args.checkpoint_4d)
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    import torch

    torch.set_num_threads(1)

    args.out.mkdir(parents=True, exist_ok=True)
    if args.data is None:
        data = args.out / "log"
        make_log(data, int(args.sequences or 2), args.frames, args.seed, args.first_sequence, args.sensor)
        seqs = None
    else:
        data = args.data
        seqs = args.sequences.split(",") if args.sequences else None
    reader = SemanticKittiReader(data)
    seqs = seqs or reader.sequences()
    gt: dict[str, tuple[list[str], list[np.ndarray]]] = {}
    for seq in seqs:
        frames = reader.frames(seq)
        gt[seq] = ([f.frame_id for f in frames], [reader.labels(f) for f in frames])
    n_frames = sum(len(ids) for ids, _ in gt.values())
    ks = [int(s) for s in args.scans.split(",")]

    os.environ.setdefault("PREFECT_LOGGING_LEVEL", "WARNING")
    from flows.server import prefect_api

    with prefect_api():  # one temporary Prefect server for every run (and the warm-up)
        if not args.no_warmup:
            warm_up(args.out / "warmup", ckpt, args.sensor)
        rows = run_all(args, data, reader, seqs, gt, ks, ckpt, ckpt4d)
        write_results(
            args,
            rows,
            n_frames,
            meta={
                "checkpoint": ckpt,
                "checkpoint_4d": ckpt4d,
                "data": str(Path(data).resolve()),
                "sequences": seqs,
                "frames": n_frames,
                "scans": ks,
                "tracker": {"rows": TRACKERS, "defaults": Tracker(LM).state_dict()["config"]},
            },
        )


def _finite(x):
    """``x`` with NaN/inf floats as None (strict JSON)."""
    if isinstance(x, dict):
        return {k: _finite(v) for k, v in x.items()}
    if isinstance(x, list):
        return [_finite(v) for v in x]
    return None if isinstance(x, float) and not math.isfinite(x) else x


def write_results(args, rows: dict[str, Row], n_frames: int, meta: dict) -> None:
    """Print the table and write ``bench_4d_model.json`` / ``.md`` under ``--out``."""
    order = [r for r in (*TRACKERS, FLOOR, "k=2", "k=3", "k=4") if r in rows]
    order += [r for r in rows if r not in order]
    results = {r: rows[r].summary(n_frames) for r in order}
    (args.out / "bench_4d_model.json").write_text(
        json.dumps(_finite({"meta": meta, "rows": results}), indent=2) + "\n"
    )
    md = markdown(results, meta)
    (args.out / "bench_4d_model.md").write_text(md)
    print()
    print(md)
    print(f"wrote {args.out / 'bench_4d_model.json'}, {args.out / 'bench_4d_model.md'}; run stores run-k*")


MODES = {"oracle": oracle_main, "model": model_main}


def main(argv: list[str]) -> None:
    if argv and argv[0] in MODES:
        MODES[argv[0]](argv[1:])
        return
    if argv:
        sys.exit(f"usage: bench_4d.py {{{'|'.join(MODES)}}} [options] (MODE --help: its options)")
    import tempfile

    out = tempfile.mkdtemp(prefix="bench-4d-")
    for mode, extra in (("oracle", []), ("model", ["--out", out])):  # each in its own process
        print(f"== bench_4d.py {mode} {' '.join(extra)}", flush=True)
        subprocess.run([sys.executable, __file__, mode, *extra], check=True)


if __name__ == "__main__":
    main(sys.argv[1:])
