"""The labelling methods side by side on the same held-out logs: DS-Net (k = 1) + track, 4D-DS-Net
(k = 2..4) + stitch, MOST (k = 1 and accumulated) + track.

Every row labels the log into its own run store through the real stages (the plain runner: the
pipeline of ``dsnet label --method M``, built by :class:`flows.request.LabelRequest` from the same
settings, without Prefect), in its own process so that its peak RSS is its own; the parent scores
each store's final labels against the ground truth (:class:`PanopticEvaluator`, official and
corrected mode) and counts identity switches along ground-truth tubes.

Columns: PQ, PQ^Th, PQ^St, mIoU, LSTQ, S_assoc (official mode), LSTQ (corrected: classes absent
from the ground truth not counted), id switches, seconds per frame of each stage (manifest wall
times; one torch thread), peak RSS of the row's process.

Default data: held-out synthetic sequences (seed 303 from sequence 60, hdl64: the bundled models
were trained on seed 101 sequences 0–15 and validated on seed 202 sequences 50–51).

Run: ``OMP_NUM_THREADS=1 .venv/bin/python bench/bench_methods.py --out DIR [--rows KEY,...]
[--data LOG --sequences 00,01] [--frames 20] [--checkpoint-most CKPT]``; ``--rows list`` prints
the rows; ``--yaw DEG`` labels a copy of the log turned by a global yaw (rotation robustness:
``DIR/yawDEG/``). Stores under ``DIR/<row>`` are kept (``dsnet dashboard`` takes several roots); a row
whose store is current is not recomputed (``--force`` recomputes). Writes ``DIR/bench_methods.json``
and ``DIR/bench_methods.md``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


@dataclass(frozen=True)
class Row:
    """One labelling configuration: ``dsnet label --method METHOD --scans SCANS [settings]``."""

    title: str
    method: str
    scans: int
    options: dict[str, Any] = field(default_factory=dict)  # the method's options (temporal)
    settings: dict[str, Any] = field(default_factory=dict)  # LabelSettings fields
    stages: dict[str, dict[str, Any]] = field(default_factory=dict)  # extra per-stage overrides
    checkpoint: str | None = None  # key of --checkpoint-KEY (default: the method's)
    prior: float | str | None = None  # D-PLS prior from ground truth: "gt", or a target mIoU


ROWS: dict[str, Row] = {
    "dsnet-k1-track": Row("DS-Net k=1 + track", "dsnet", 1, {"temporal": "track"}),
    "dsnet-k2-stitch": Row("4D-DS-Net k=2 + stitch", "dsnet", 2, {"temporal": "stitch"}),
    "dsnet-k3-stitch": Row("4D-DS-Net k=3 + stitch", "dsnet", 3, {"temporal": "stitch"}),
    "dsnet-k4-stitch": Row("4D-DS-Net k=4 + stitch", "dsnet", 4, {"temporal": "stitch"}),
    "most-k1-track": Row("MOST k=1 + track", "most", 1),
    "most-k3-track": Row("MOST k=3 + track", "most", 3),
    "dsnet-k1-tta2": Row("DS-Net k=1 + track, --tta 2", "dsnet", 1, {"temporal": "track"}, {"tta": 2}),
    "dsnet-k1-tta4": Row("DS-Net k=1 + track, --tta 4", "dsnet", 1, {"temporal": "track"}, {"tta": 4}),
    "dsnet-k1-tta8": Row("DS-Net k=1 + track, --tta 8", "dsnet", 1, {"temporal": "track"}, {"tta": 8}),
    "dsnet-k2-tta4": Row("4D-DS-Net k=2 + stitch, --tta 4", "dsnet", 2, {"temporal": "stitch"}, {"tta": 4}),
    "dsnet-k1-ground": Row(
        "DS-Net k=1 + track, --match ground", "dsnet", 1, {"temporal": "track"}, {"match": "ground"}
    ),
    "dsnet-k1-both": Row(
        "DS-Net k=1 + track, --match both", "dsnet", 1, {"temporal": "track"}, {"match": "both"}
    ),
    "dsnet-k2-ground": Row(
        "4D-DS-Net k=2 + stitch, --match ground", "dsnet", 2, {"temporal": "stitch"}, {"match": "ground"}
    ),
    "dsnet-k2-both": Row(
        "4D-DS-Net k=2 + stitch, --match both", "dsnet", 2, {"temporal": "stitch"}, {"match": "both"}
    ),
    "eq4-k1-track": Row(
        "Eq-4D n=4 (tiny lifted, instance head 1 epoch) k=1 + track",
        "dsnet",
        1,
        {"temporal": "track"},
        {"equivariant": 4},
        checkpoint="eq4",
    ),
    "dpls-k2-model": Row(
        "D-PLS k=2 + stitch, prior: bundled DS-Net semantics", "dpls", 2, {"temporal": "stitch"}
    ),
    "dpls-k2-gt": Row(
        "D-PLS k=2 + stitch, prior: ground truth", "dpls", 2, {"temporal": "stitch"}, prior="gt"
    ),
    "dpls-k2-gt0.8": Row(
        "D-PLS k=2 + stitch, prior: GT corrupted to mIoU 0.8", "dpls", 2, {"temporal": "stitch"}, prior=0.8
    ),
    "dpls-k2-gt0.6": Row(
        "D-PLS k=2 + stitch, prior: GT corrupted to mIoU 0.6", "dpls", 2, {"temporal": "stitch"}, prior=0.6
    ),
    "most-k3-distance": Row(
        "MOST k=3 + track, distance memberships", "most", 3, stages={"most": {"rule": "distance"}}
    ),
}
DEFAULT_ROWS = (
    "dsnet-k1-track",
    "dsnet-k2-stitch",
    "dsnet-k3-stitch",
    "dsnet-k4-stitch",
    "most-k1-track",
    "most-k3-track",
)


def make_log(root: Path, sequences: int, frames: int, seed: int, first: int, sensor: str) -> None:
    """Generate the held-out synthetic log at ``root`` unless the same one is already there."""
    from dsnet_core.synth import generate_log

    stamp = root / "bench_log.json"
    want = {"sequences": sequences, "frames": frames, "seed": seed, "first_sequence": first, "sensor": sensor}
    if stamp.exists() and json.loads(stamp.read_text()) == want:
        return
    generate_log(root, sequences=sequences, frames=frames, seed=seed, sensor=sensor, first_sequence=first,
                 overwrite=True)  # fmt: skip
    stamp.write_text(json.dumps(want) + "\n")


def request_of(
    row: Row,
    data: Path,
    store: Path,
    seqs: list[str],
    checkpoints: dict[str, str | None],
    refine: bool | None = None,
):
    """The :class:`~flows.request.LabelRequest` ``dsnet label`` would build for ``row`` (``refine``:
    ``--refine/--no-refine``, None for the method's default)."""
    from flows.request import LabelRequest
    from tasks.methods import stage_configs

    settings = {"checkpoint": checkpoints.get(row.checkpoint or row.method), **row.settings}
    if row.prior is not None:
        settings["semantic_prior"] = str(prior_dir(store.parent, row.prior))
    stages = stage_configs(row.method, scans=row.scans, **settings)
    for name, over in row.stages.items():
        stages[name] = {**stages.get(name, {}), **over}
    return LabelRequest(
        data=str(data),
        root=str(store),
        sequences=seqs,
        method=row.method,
        method_options=row.options if refine is None else {**row.options, "refine": refine},
        stages=stages,
    )


def prior_dir(out: Path, prior: float | str) -> Path:
    """Where the prior files of a D-PLS row live (written by the parent before the row runs)."""
    return out / "priors" / (str(prior) if prior == "gt" else f"gt-miou{prior:g}")


def label_row(
    key: str,
    data: Path,
    store: Path,
    seqs: list[str],
    checkpoints: dict,
    force: bool,
    refine: bool | None = None,
) -> dict:
    """Run every stage of the row's pipeline (this process); stage seconds (but score's) and peak RSS."""
    import torch

    from storage.run import RunStore
    from tests.helpers.plain_runner import run_stage_plain

    torch.set_num_threads(1)
    request = request_of(ROWS[key], data, store, seqs, checkpoints, refine)
    pipeline = request.pipeline()
    run = {
        **pipeline.record(),
        "data": str(data),
        "format": "auto",
        "sequences": seqs,
        "stages": request.stage_configs(pipeline),
        "options": {"block_size": 25},
    }
    rs = RunStore(store)
    rs.write_run_config("bench", run)
    seconds: dict[str, float] = {}
    for seq in seqs:
        for stage in pipeline.names():
            m = run_stage_plain(rs, pipeline, seq, stage, run, "bench", force=force)
            if stage != "score":  # scored so that `dsnet dashboard` can show the stores side by side
                seconds[stage] = seconds.get(stage, 0.0) + float(m.timings.get("wall_s", 0.0))
    from flows.report.merge import write_report

    write_report(rs, pipeline)  # the report tables `dsnet dashboard` reads
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return {"stages": seconds, "peak_rss_mb": peak, "labels": pipeline.labels}


class Scores:
    """Official- and corrected-mode evaluators and identity switches over a row's frames."""

    def __init__(self, label_map) -> None:
        from dsnet_core.metrics import PanopticEvaluator
        from dsnet_core.metrics.switches import SwitchCounter

        self.evals = {
            m: PanopticEvaluator(label_map, mode=m, keep_rows=False) for m in ("official", "corrected")
        }
        self.switches = SwitchCounter(label_map)
        self.names = list(label_map.class_names)

    def add(self, seq: str, frame: str, gt: np.ndarray, pred: np.ndarray) -> None:
        for ev in self.evals.values():
            ev.add(gt, pred, frame=frame, sequence=seq)
        self.switches.add(gt, pred, sequence=seq)

    def summary(self) -> dict:
        o, c = self.evals["official"].result(), self.evals["corrected"].result()
        p = o.panoptic
        return {
            "pq": p.pq,
            "pq_things": p.pq_things,
            "pq_stuff": p.pq_stuff,
            "miou": p.miou,
            "lstq": o.lstq.lstq,
            "s_assoc": o.lstq.s_assoc,
            "lstq_corrected": c.lstq.lstq,
            "pq_things_corrected": c.panoptic.pq_things,
            "id_switches": self.switches.switches,
            "class_iou": {name: score.iou for name, score in p.per_class.items()},
            "class_pq": {name: score.pq for name, score in p.per_class.items()},
            "class_things": [name for name, score in p.per_class.items() if score.thing],
            # points per (predicted, ground-truth) train class, official mode; names by train id
            "confusion": self.evals["official"].panoptic.conf.tolist(),
            "class_names": self.names,
        }


def score_row(store: Path, reader, seqs: list[str], label_map) -> dict:
    """Scores of a row's stored final labels (its method's labels stage)."""
    from storage.run import RunStore
    from tasks.run_config import read_run

    rs = RunStore(store)
    pipeline = read_run(rs).pipeline()
    scores = Scores(label_map)
    for seq in seqs:
        labels = rs.arrays(seq, pipeline[pipeline.labels].contract)
        for ref in reader.frames(seq):
            scores.add(seq, ref.frame_id, reader.labels(ref), labels.read_item(ref.index)["label"])
    return scores.summary()


def markdown(results: dict[str, dict], meta: dict) -> str:
    stages = sorted({s for r in results.values() for s in r["s_per_frame"]}, key=STAGE_ORDER.index)
    head = ["row", "PQ", "PQ^Th", "PQ^St", "mIoU", "LSTQ", "S_assoc", "LSTQ corr.", "id sw.", "s/frame"]
    lines = [
        "# Methods side by side",
        "",
        f"{meta['frames']} frames of {meta['data']} ({', '.join(meta['sequences'])}); checkpoints: "
        + ", ".join(f"{m} {c or 'bundled'}" for m, c in meta["checkpoints"].items()),
        "",
        "| " + " | ".join([*head, *(f"{s} s/f" for s in stages), "peak RSS MB"]) + " |",
        "|" + "---|" * (len(head) + len(stages) + 1),
    ]
    for key, r in results.items():
        s = r["scores"]
        cells = [ROWS[key].title] + [
            f"{s[k]:.3f}" for k in ("pq", "pq_things", "pq_stuff", "miou", "lstq", "s_assoc")
        ]
        cells += [
            f"{s['lstq_corrected']:.3f}",
            str(s["id_switches"]),
            f"{sum(r['s_per_frame'].values()):.2f}",
        ]
        cells += [f"{r['s_per_frame'][st]:.3f}" if st in r["s_per_frame"] else "" for st in stages]
        cells.append(f"{r['peak_rss_mb']:.0f}")
        lines.append("| " + " | ".join(cells) + " |")
    lines += [
        "",
        "Official mode unless marked corr. (classes absent from the ground truth not counted); id sw.: "
        "identity switches along ground-truth tubes; s/frame: the stages' manifest wall times (ingest "
        "to the labels stage, one torch thread) per frame; peak RSS: the row's own process.",
    ]
    return "\n".join(lines) + "\n"


STAGE_ORDER = [
    *("ingest", "align", "prior", "dpls", "infer", "most", "shift", "fuse", "stitch", "track", "refine")
]


def _finite(x):
    if isinstance(x, dict):
        return {k: _finite(v) for k, v in x.items()}
    return None if isinstance(x, float) and not math.isfinite(x) else x


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--out",
        type=Path,
        default=None,
        help="folder of the run stores and tables (default: a new temp folder)",
    )
    ap.add_argument("--rows", default=",".join(DEFAULT_ROWS), help="comma-separated row keys, or 'list'")
    ap.add_argument("--data", type=Path, default=None, help="SemanticKITTI-layout log with labels and poses")
    ap.add_argument("--sequences", default=None, help="with --data: names; else how many to generate (2)")
    ap.add_argument("--frames", type=int, default=20, help="frames per generated sequence")
    ap.add_argument("--sensor", default="hdl64")
    ap.add_argument("--seed", type=int, default=303)
    ap.add_argument("--first-sequence", type=int, default=60)
    ap.add_argument("--checkpoint-dsnet", default=None, help="DS-Net checkpoint (default: the bundled ones)")
    ap.add_argument("--checkpoint-most", default=None, help="MOST checkpoint (default: the bundled one)")
    ap.add_argument("--checkpoint-dpls", default=None, help="D-PLS checkpoint (default: the bundled one)")
    ap.add_argument("--checkpoint-eq4", default=None, help="C_4 DS-Net checkpoint (the eq4 rows need it)")
    ap.add_argument(
        "--yaw", type=float, default=None, help="label a copy of the log turned by this yaw (deg)"
    )
    ap.add_argument("--force", action="store_true", help="recompute every stage")
    ap.add_argument(
        "--refine",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="end with refine (default: the method's default); --no-refine scores the model's own labels",
    )
    ap.add_argument("--row", default=None, help=argparse.SUPPRESS)  # worker: label one row, print JSON
    args = ap.parse_args()
    args.out = args.out or Path(tempfile.mkdtemp(prefix="bench-methods-"))
    if args.rows == "list":
        for key, row in ROWS.items():
            print(f"{key:24s} {row.title}")
        return
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    checkpoints = {
        "dsnet": args.checkpoint_dsnet,
        "most": args.checkpoint_most,
        "dpls": args.checkpoint_dpls,
        "eq4": args.checkpoint_eq4,
    }
    checkpoints = {m: str(Path(c).resolve()) if c else None for m, c in checkpoints.items()}
    if args.data is None:
        data = args.out / "log"
        if args.row is None:
            make_log(data, int(args.sequences or 2), args.frames, args.seed, args.first_sequence, args.sensor)
    else:
        data = args.data
    if args.yaw is not None and args.row is None:
        from _yaw import rotate_log

        data = rotate_log(data, args.out / f"log-yaw{args.yaw:g}", args.yaw)
        args.out = args.out / f"yaw{args.yaw:g}"
        args.out.mkdir(parents=True, exist_ok=True)
    from dsnet_core.io.semantickitti import SemanticKittiReader
    from dsnet_core.labels import load_label_map

    reader = SemanticKittiReader(data)
    seqs = args.sequences.split(",") if (args.data and args.sequences) else reader.sequences()
    if args.row is not None:
        out = label_row(args.row, data, args.out / args.row, seqs, checkpoints, args.force, args.refine)
        print("ROW " + json.dumps(out))
        return
    keys = args.rows.split(",")
    unknown = [k for k in keys if k not in ROWS]
    if unknown:
        raise SystemExit(f"unknown rows {unknown}; --rows list shows them")
    label_map = load_label_map("semantic-kitti")
    n_frames = sum(len(reader.frames(s)) for s in seqs)
    results: dict[str, dict] = {}
    for key in keys:
        row = ROWS[key]
        if row.checkpoint and not checkpoints.get(row.checkpoint):
            raise SystemExit(f"row {key} needs --checkpoint-{row.checkpoint}")
        if row.prior is not None:
            from _priors import write_prior

            rec = write_prior(data, prior_dir(args.out, row.prior), None if row.prior == "gt" else row.prior)
            print(f"{row.title}: prior mIoU {rec['miou']:.3f} (confusion scale {rec['scale']:.3f})")
        cmd = [sys.executable, __file__, "--out", str(args.out), "--row", key, "--data", str(data)]
        cmd += ["--sequences", ",".join(seqs)]
        for m, c in checkpoints.items():
            if c:
                cmd += [f"--checkpoint-{m}", c]
        if args.force:
            cmd.append("--force")
        if args.refine is not None:
            cmd.append("--refine" if args.refine else "--no-refine")
        t0 = time.perf_counter()
        res = subprocess.run(cmd, capture_output=True, text=True)
        if res.returncode != 0:
            raise SystemExit(f"row {key} failed:\n{res.stderr[-3000:]}")
        line = [x for x in res.stdout.splitlines() if x.startswith("ROW ")][-1]
        out = json.loads(line[4:])
        results[key] = {
            "title": ROWS[key].title,
            "s_per_frame": {s: v / n_frames for s, v in out["stages"].items()},
            "peak_rss_mb": out["peak_rss_mb"],
            "scores": score_row(args.out / key, reader, seqs, label_map),
        }
        sc = results[key]["scores"]
        print(
            f"{ROWS[key].title}: PQ {sc['pq']:.3f} LSTQ {sc['lstq']:.3f} ({time.perf_counter() - t0:.0f} s)"
        )
    meta = {
        "data": str(Path(data).resolve()),
        "sequences": seqs,
        "frames": n_frames,
        "checkpoints": checkpoints,
    }
    (args.out / "bench_methods.json").write_text(
        json.dumps(_finite({"meta": meta, "rows": results}), indent=2) + "\n"
    )
    md = markdown(results, meta)
    (args.out / "bench_methods.md").write_text(md)
    print()
    print(md)


if __name__ == "__main__":
    main()
