"""Refine on vs off: the same labels scored before and after the ``refine`` stage.

For every cell (a held-out synthetic log of ``dsnet synth``: sensor, street style and seed held
out from the bundled models' training, or a log of the second generator in
``../shared/validation/``, read-only) and every method row, the method's stages label the log
into one run store (the plain runner, no Prefect), then ``refine`` runs on the method's final
labels. Both label arrays of that store are scored against the ground truth (official mode:
PQ, PQ^Th, PQ^St, mIoU, LSTQ; identity switches along ground-truth tubes), so before and after
differ only by refine. Also: refine's seconds per frame against the label stages'.

Run: ``OMP_NUM_THREADS=1 .venv/bin/python bench/bench_refine.py --out DIR [--rows dsnet-k1-track,...]
[--cells hdl64:classic:303:60,vlp32:random:304:70,validation:123] [--frames 20] [--set window=5 ...]``.
``--rows list`` prints the rows. Stores under ``DIR/<cell>/<row>`` are kept and reused; refine
is recomputed when ``--set`` changes its config. Writes ``DIR/bench_refine.json`` and ``.md``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
VALIDATION = next(
    (p / "shared" / "validation" for p in REPO.parents if (p / "shared" / "validation").is_dir()),
    REPO.parent / "shared" / "validation",
)  # ../shared/validation beside the checkout (or beside a folder of worktrees)


@dataclass(frozen=True)
class Row:
    """A labelling method: ``dsnet label --method METHOD --scans SCANS [--temporal T]``."""

    title: str
    method: str
    scans: int
    options: dict[str, Any] = field(default_factory=dict)


ROWS = {
    "dsnet-k1-track": Row("DS-Net k=1 + track", "dsnet", 1, {"temporal": "track"}),
    "dsnet-k2-stitch": Row("4D-DS-Net k=2 + stitch", "dsnet", 2, {"temporal": "stitch"}),
    "dsnet-k2-track": Row("4D-DS-Net k=2 + track", "dsnet", 2, {"temporal": "track"}),
    "most-k1-track": Row("MOST k=1 + track", "most", 1),
    "dpls-k2-stitch": Row("D-PLS k=2 + stitch", "dpls", 2, {"temporal": "stitch"}),
}
DEFAULT_CELLS = "hdl64:classic:303:60,vlp32:random:304:70,validation"


def make_cell(out: Path, cell: str, frames: int) -> Path:
    """The log of ``cell`` under ``out`` (generated once): ``sensor:style:seed:first`` or ``validation``."""
    root = out / "logs" / cell.replace(":", "-")
    stamp = root / "bench_log.json"
    if stamp.exists() and json.loads(stamp.read_text()) == {"cell": cell, "frames": frames}:
        return root
    if cell.split(":")[0] == "validation":
        if not (VALIDATION / "other_generator.py").exists():
            raise SystemExit(f"{VALIDATION} is absent: leave 'validation' out of --cells")
        sys.path.insert(0, str(VALIDATION))
        import other_generator

        seed = int(cell.split(":")[1]) if ":" in cell else 123
        other_generator.write_sequence(str(root), seq=8, n_frames=frames, seed=seed)
    else:
        from dsnet_core.synth import generate_log

        sensor, style, seed, first = cell.split(":")
        generate_log(root, sequences=1, frames=frames, seed=int(seed), sensor=sensor, style=style,
                     first_sequence=int(first), overwrite=True)  # fmt: skip
    stamp.write_text(json.dumps({"cell": cell, "frames": frames}) + "\n")
    return root


def pipeline_of(row: Row):
    """The row's method with ``refine`` after its labels stage (its own score stage left out)."""
    from tasks.methods import get_pipeline

    plain, refined = (
        get_pipeline(row.method, **row.options, refine=False),
        get_pipeline(row.method, **row.options, refine=True),
    )
    return refined, plain.labels


def label(row: Row, data: Path, store: Path, refine: dict[str, Any]) -> dict[str, Any]:
    """Run the row's stages and refine on every sequence of ``data``; seconds per frame by stage."""
    import torch

    from dsnet_core.io.formats import open_log
    from storage.run import RunStore
    from tasks.methods import stage_configs
    from tests.helpers.plain_runner import run_stage_plain

    torch.set_num_threads(1)
    pipeline, labels = pipeline_of(row)
    stages = stage_configs(row.method, scans=row.scans)
    stages["refine"] = refine
    run = {**pipeline.record(), "data": str(data), "format": "auto", "stages": stages,
           "options": {"block_size": 25}}  # fmt: skip
    rs = RunStore(store)
    rs.write_run_config("bench", run)
    reader = open_log(str(data))
    seconds: dict[str, float] = {}
    frames = 0
    for seq in reader.sequences():
        frames += len(reader.frames(seq))
        for stage in [s for s in pipeline.names() if s != "score"]:
            m = run_stage_plain(rs, pipeline, seq, stage, run, "bench")
            seconds[stage] = seconds.get(stage, 0.0) + float(m.timings.get("wall_s", 0.0))
    return {"rs": rs, "pipeline": pipeline, "labels": labels, "reader": reader,
            "s_per_frame": {k: v / max(frames, 1) for k, v in seconds.items()}}  # fmt: skip


def scores(rs, pipeline, stage: str, reader, label_map) -> dict[str, float]:
    """Official-mode PQ family, mIoU, LSTQ and identity switches of ``stage``'s labels."""
    from dsnet_core.metrics import PanopticEvaluator
    from dsnet_core.metrics.switches import SwitchCounter

    ev = PanopticEvaluator(label_map, keep_rows=False)
    sw = SwitchCounter(label_map)
    for seq in reader.sequences():
        arrays = rs.arrays(seq, pipeline[stage].contract)
        done = arrays.done()
        for ref in reader.frames(seq):
            if not done[ref.index]:
                continue
            gt, pred = reader.labels(ref), arrays.read_item(ref.index)["label"]
            ev.add(gt, pred, frame=ref.frame_id, sequence=seq)
            sw.add(gt, pred, sequence=seq)
    r = ev.result()
    p = r.panoptic
    return {"pq": p.pq, "pq_things": p.pq_things, "pq_stuff": p.pq_stuff, "miou": p.miou,
            "lstq": r.lstq.lstq, "id_switches": sw.switches}  # fmt: skip


KEYS = ("pq", "pq_things", "pq_stuff", "miou", "lstq", "id_switches")


def markdown(results: list[dict], refine: dict[str, Any]) -> str:
    head = ["cell", "row", *(k for k in KEYS), "refine s/f", "labels s/f", "share"]
    lines = ["# Refine on vs off", "", f"refine settings: {refine or 'defaults'}", "",
             "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]  # fmt: skip
    for r in results:
        b, a = r["before"], r["after"]
        cells = [r["cell"], r["row"]]
        for k in KEYS:
            fmt = "{:d}" if k == "id_switches" else "{:.3f}"
            cells.append(f"{fmt.format(b[k])} → {fmt.format(a[k])}")
        spf = r["s_per_frame"]
        label_s = sum(v for k, v in spf.items() if k != "refine")
        cells += [f"{spf['refine']:.3f}", f"{label_s:.3f}", f"{spf['refine'] / max(label_s, 1e-9):.0%}"]
        lines.append("| " + " | ".join(cells) + " |")
    lines += ["", "Official mode; id switches along ground-truth tubes; s/f: manifest wall seconds per frame "
              "(one torch thread); share: refine's time over the label stages'."]  # fmt: skip
    return "\n".join(lines) + "\n"


def _finite(x):
    if isinstance(x, dict):
        return {k: _finite(v) for k, v in x.items()}
    return None if isinstance(x, float) and not math.isfinite(x) else x


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=None, help="output folder (default: a new temporary folder)")
    ap.add_argument("--rows", default="dsnet-k1-track,dsnet-k2-stitch", help="row keys, or 'list'")
    ap.add_argument("--cells", default=DEFAULT_CELLS, help="sensor:style:seed:first_sequence, or validation")
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--set", action="append", default=[], help="refine setting KEY=VALUE (JSON value)")
    args = ap.parse_args()
    args.out = args.out or Path(tempfile.mkdtemp(prefix="bench-refine-"))
    if args.rows == "list":
        for key, row in ROWS.items():
            print(f"{key:18s} {row.title}")
        return
    from dsnet_core.labels import load_label_map
    from tasks.refine import RefineConfig

    refine = {k: json.loads(v) for k, v in (s.split("=", 1) for s in args.set)}
    RefineConfig.model_validate(refine)  # unknown keys and bad values fail here
    label_map = load_label_map("semantic-kitti")
    results = []
    for cell in args.cells.split(","):
        data = make_cell(args.out, cell, args.frames)
        for key in args.rows.split(","):
            lab = label(ROWS[key], data, args.out / cell.replace(":", "-") / key, refine)
            before = scores(lab["rs"], lab["pipeline"], lab["labels"], lab["reader"], label_map)
            after = scores(lab["rs"], lab["pipeline"], "refine", lab["reader"], label_map)
            results.append({"cell": cell, "row": key, "before": before, "after": after,
                            "s_per_frame": lab["s_per_frame"]})  # fmt: skip
            print(
                f"{cell} {key}: " + ", ".join(f"{k} {before[k]:.3f}->{after[k]:.3f}" for k in KEYS),
                flush=True,
            )
    pq = np.array([r["after"]["pq"] - r["before"]["pq"] for r in results])
    print(f"mean PQ change {pq.mean():+.4f}, worst {pq.min():+.4f}")
    (args.out / "bench_refine.json").write_text(json.dumps(_finite({"refine": refine, "results": results}),
                                                           indent=1) + "\n")  # fmt: skip
    (args.out / "bench_refine.md").write_text(markdown(results, refine))
    print(markdown(results, refine))


if __name__ == "__main__":
    main()
