"""Adaptation without labels: ``dsnet adapt`` on each target's unlabelled sequences, scored on those
sequences (what an auto-labeller does) and on disjoint sequences of the same target, and on the
source domain (does it forget?).

Source = the bundled default (``tiny-v2``, k = 1). Targets, none of which the bundled model saw:

- ``styles``: crossroads / T-junctions and parking lots (styles training never drew);
- ``sensors``: VLP-32C and the nuScenes-like 32-beam pattern (sensors training never drew);
- ``physics``: a ``dsnet synth`` log with altered physics (:data:`PHYSICS`: 40 beams +8°…−22°,
  mounted at 2.3 m, remission gain 0.45 with a 40 m fall-off, 12 % ray drop);
- ``validation``: the second generator of ``../shared/validation/`` (read-only; its labels are read
  only to score and for the card's precision record, never by the student).

``source`` is a held-out seed of the training styles and sensors. For each target: label the
adaptation (A) and disjoint (D) sequences with the source model, ``dsnet adapt A --out ...``
(timed), label A and D (and the source cell) with the adapted model, score (official mode, k = 1 +
track, refine off for every model, so before and after differ only by the weights). With
``--reference``, also ``dsnet train dsnet A --init-from SOURCE`` on A's ground truth with the same
steps and learning rate (the model trained with labels on the target) and the share of the gap closed.

Run: ``OMP_NUM_THREADS=1 .venv/bin/python bench/bench_adapt.py --out DIR [--targets
styles,sensors,physics,validation] [--steps 200] [--rounds 1] [--reference]``. Logs, stores,
checkpoints and scores under DIR are kept and reused (delete a target's folder to redo it). Writes
``DIR/bench_adapt.json`` and ``.md``.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
VALIDATION = next(
    (p / "shared" / "validation" for p in REPO.parents if (p / "shared" / "validation").is_dir()),
    REPO.parent / "shared" / "validation",
)
PHYSICS = ["elevations=uniform:40:8:-22", "height=2.3", "remission_gain=0.45", "falloff=40", "dropout=0.12"]
#: target → set → (seed, first sequence, frames, [(style, sensor)]); validation: (seed, seq, frames, None)
TARGETS = {
    "styles": {
        "A": (414, 70, 12, [("junction", "hdl64"), ("parking_lot", "ouster64")]),
        "D": (424, 72, 8, [("junction", "vlp16"), ("parking_lot", "hdl64")]),
    },
    "sensors": {
        "A": (515, 80, 12, [("residential", "vlp32"), ("downtown", "nuscenes32")]),
        "D": (525, 82, 8, [("arterial", "vlp32"), ("country", "nuscenes32")]),
    },
    "physics": {
        "A": (616, 84, 12, [("residential", "hdl64"), ("arterial", "hdl64")]),
        "D": (626, 86, 8, [("downtown", "hdl64"), ("country", "hdl64")]),
    },
    "validation": {"A": (123, 8, 12, None), "D": (131, 10, 8, None)},
}
SOURCE = (909, 90, 8, [("residential", "hdl64"), ("country", "ouster64")])
DSNET = [sys.executable, "-m", "flows.cli"]


def make_set(root: Path, spec: tuple, physics: list[str] | None = None, validation: bool = False) -> Path:
    """Generate one set of sequences under ``root`` (once)."""
    seed, first, frames, setups = spec
    stamp = root / "bench_set.json"
    want = {"spec": json.loads(json.dumps(spec)), "physics": physics, "validation": validation}
    if stamp.exists() and json.loads(stamp.read_text()) == want:
        return root
    if validation:
        if not (VALIDATION / "other_generator.py").exists():
            raise SystemExit(f"{VALIDATION} is absent: leave 'validation' out of --targets")
        sys.path.insert(0, str(VALIDATION))
        import other_generator

        for k in range(2):
            other_generator.write_sequence(str(root), seq=first + k, n_frames=frames, seed=seed + k)
    else:
        from dsnet_core.synth import generate_log
        from dsnet_core.synth.physics import parse_physics

        for i, (style, sensor) in enumerate(setups):
            generate_log(
                root,
                sequences=1,
                frames=frames,
                seed=seed,
                sensor=sensor,
                style=style,
                first_sequence=first + i,
                overwrite=True,
                physics=parse_physics(physics),
            )
    stamp.write_text(json.dumps(want) + "\n")
    return root


def score(ckpt: Path, data: Path, store: Path, cache: Path) -> dict:
    """Label ``data`` with ``ckpt`` (k = 1 + track, no refine; plain runner) and score it (cached)."""
    if cache.is_file():
        return json.loads(cache.read_text())
    import torch

    from dsnet_core.io.formats import open_log
    from dsnet_core.labels import load_label_map
    from dsnet_core.metrics import PanopticEvaluator
    from storage.run import RunStore
    from tasks.methods import LabelSettings, get_method
    from tests.helpers.plain_runner import run_stage_plain

    torch.set_num_threads(1)
    method = get_method("dsnet")
    settings = LabelSettings(scans=1, checkpoint=str(ckpt), refine=False)
    stages = method.stage_settings(settings)
    pipeline = method.pipeline(method.options(settings), stages)
    stages.setdefault("ingest", {})["grid"] = method.model_grid(stages)
    run = {**pipeline.record(), "data": str(data), "format": "auto", "stages": stages}
    rs = RunStore(store)
    rs.write_run_config("bench", run)
    reader = open_log(str(data))
    ev = PanopticEvaluator(load_label_map("semantic-kitti"), keep_rows=False)
    t0 = time.perf_counter()
    for seq in reader.sequences():
        for stage in [*pipeline.upstream_closure(pipeline.labels), pipeline.labels]:
            run_stage_plain(rs, pipeline, seq, stage, run, "bench")
        arrays = rs.arrays(seq, pipeline[pipeline.labels].contract)
        for ref in reader.frames(seq):
            ev.add(reader.labels(ref), arrays.read_item(ref.index)["label"], frame=ref.frame_id, sequence=seq)
    p = ev.result().panoptic
    iou = {name: round(c.iou, 4) for name, c in p.per_class.items()}
    out = {
        "pq": p.pq,
        "miou": p.miou,
        "pq_things": p.pq_things,
        "pq_stuff": p.pq_stuff,
        "class_iou": iou,
        "seconds": round(time.perf_counter() - t0, 1),
    }
    cache.parent.mkdir(parents=True, exist_ok=True)
    cache.write_text(json.dumps(out, indent=1) + "\n")
    return out


def run_cmd(cmd: list[str], log: Path) -> tuple[float, float, float]:
    """Run a ``dsnet`` command (output to ``log``); its wall seconds, its CPU seconds (user + system,
    the process and its children) and the machine's mean 1-minute load average while it ran (the
    machine is shared: CPU seconds are what it would take alone on one core)."""
    env = {**os.environ, "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1"}
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    loads: list[float] = []
    with open(log, "w") as f:
        proc = subprocess.Popen(cmd, cwd=REPO, env=env, stdout=f, stderr=subprocess.STDOUT)
        while proc.poll() is None:
            loads.append(os.getloadavg()[0])
            time.sleep(5)
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed (see {log})")
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return time.perf_counter() - t0, cpu, sum(loads) / max(len(loads), 1)


def adapt(data: Path, out: Path, args) -> dict:
    """``dsnet adapt`` on ``data`` (once); its command, wall time and the card's round records."""
    stamp = out.with_suffix(".json")
    cmd = [
        *DSNET,
        "adapt",
        str(data),
        "--out",
        str(out),
        "--steps",
        str(args.steps),
        "--rounds",
        str(args.rounds),
        "--epochs",
        "1",
        "--lr",
        str(args.lr),
        *args.adapt_args.split(),
    ]
    if stamp.is_file() and json.loads(stamp.read_text())["command"] == cmd[2:]:
        return json.loads(stamp.read_text())
    if out.exists():
        cmd.append("--resume")
    seconds, cpu, load = run_cmd(cmd, out.parent / "adapt.log")
    card = json.loads((out / "card.json").read_text())
    rec = {
        "command": cmd[2:] if cmd[-1] != "--resume" else cmd[2:-1],
        "seconds": round(seconds, 1),
        "cpu_seconds": round(cpu, 1),
        "load": round(load, 1),
        "rounds": card["training_data"]["adapt"]["rounds"],
        "metrics": card["metrics"],
    }
    stamp.write_text(json.dumps(rec, indent=1) + "\n")
    return rec


def reference(data: Path, out: Path, parent: Path, args) -> float:
    """The model trained with labels on the target: the parent fine-tuned on A's ground truth."""
    if (out / "card.json").is_file():
        return 0.0
    frames = sum(1 for _ in data.glob("sequences/*/velodyne/*.bin"))
    epochs = max(1, round(args.steps * args.rounds / frames))
    cmd = [
        *DSNET,
        "train",
        "dsnet",
        str(data),
        "--out",
        str(out),
        "--init-from",
        str(parent),
        "--epochs",
        f"semantic=0,offset=0,joint={epochs},shift=0",
        "--lr",
        str(args.lr),
        "--schedule",
        "constant",
    ]
    return run_cmd(cmd, out.parent / "reference.log")[0]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=None, help="output folder (default: a new temporary folder)")
    ap.add_argument("--targets", default="styles,sensors,physics,validation")
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--rounds", type=int, default=1)
    ap.add_argument("--lr", type=float, default=1e-3, help="learning rate of adapt and of the reference")
    ap.add_argument("--adapt-args", default="", help="more dsnet adapt options, e.g. '--keep 0.3'")
    ap.add_argument("--reference", action="store_true", help="also fine-tune on A's ground truth")
    args = ap.parse_args()
    args.out = args.out or Path(tempfile.mkdtemp(prefix="bench-adapt-"))
    from dsnet_core.checkpoints import bundled_checkpoint

    parent = bundled_checkpoint(1)
    out = args.out
    src = make_set(out / "logs" / "source", SOURCE)
    results = {"parent": str(parent), "steps": args.steps, "rounds": args.rounds, "targets": {}}
    base_src = score(parent, src, out / "stores" / "source-parent", out / "scores" / "source-parent.json")
    results["source_parent"] = base_src
    for name in args.targets.split(","):
        sets = TARGETS[name]
        phys = PHYSICS if name == "physics" else None
        data = {k: make_set(out / "logs" / name / k, v, phys, name == "validation") for k, v in sets.items()}
        row = {"before": {}, "after": {}, "reference": {}}
        for k, d in data.items():
            row["before"][k] = score(
                parent, d, out / "stores" / name / f"{k}-parent", out / "scores" / name / f"{k}-parent.json"
            )
        ckpt = out / name / "adapted"
        ckpt.parent.mkdir(parents=True, exist_ok=True)
        row["adapt"] = adapt(data["A"], ckpt, args)
        for k, d in data.items():
            row["after"][k] = score(
                ckpt, d, out / "stores" / name / f"{k}-adapted", out / "scores" / name / f"{k}-adapted.json"
            )
        row["source_after"] = score(
            ckpt, src, out / "stores" / name / "source-adapted", out / "scores" / name / "source-adapted.json"
        )
        if args.reference:
            ref = out / name / "reference"
            row["reference_seconds"] = reference(data["A"], ref, parent, args)
            for k, d in data.items():
                row["reference"][k] = score(
                    ref,
                    d,
                    out / "stores" / name / f"{k}-reference",
                    out / "scores" / name / f"{k}-reference.json",
                )
        results["targets"][name] = row
        print(line(name, row, base_src), flush=True)
        (out / "bench_adapt.json").write_text(json.dumps(results, indent=1) + "\n")
    md = markdown(results)
    (out / "bench_adapt.md").write_text(md)
    print(md)


def line(name: str, row: dict, src: dict) -> str:
    b, a = row["before"], row["after"]
    sets = [
        f"{k} PQ {b[k]['pq']:.3f}->{a[k]['pq']:.3f} mIoU {b[k]['miou']:.3f}->{a[k]['miou']:.3f}" for k in "AD"
    ]
    source = f"source mIoU {src['miou']:.3f}->{row['source_after']['miou']:.3f}"
    return f"{name}: {'; '.join(sets)}; {source}; adapt {row['adapt']['seconds']:.0f} s"


def markdown(results: dict) -> str:
    head = [
        "target",
        "set",
        "PQ before → after",
        "ΔPQ",
        "mIoU before → after",
        "ΔmIoU",
        "reference PQ / mIoU",
        "gap closed PQ / mIoU",
        "coverage",
        "precision",
        "adapt wall s (CPU s, load)",
    ]
    lines = [
        f"source {results['parent']}, {results['rounds']} round(s) × {results['steps']} steps",
        "",
        "| " + " | ".join(head) + " |",
        "|" + "---|" * len(head),
    ]
    src = results["source_parent"]
    for name, row in results["targets"].items():
        last = row["adapt"]["rounds"][-1] if row["adapt"]["rounds"] else {}
        ad = row["adapt"]
        timing = f"{ad['seconds']:.0f}" + (
            f" ({ad['cpu_seconds']:.0f}, {ad['load']:.1f})" if "load" in ad else ""
        )
        for k in ("A", "D"):
            b, a, r = row["before"][k], row["after"][k], row["reference"].get(k)
            ref = gap = "–"
            if r:
                ref = f"{r['pq']:.3f} / {r['miou']:.3f}"
                gap = " / ".join(_gap(b[m], a[m], r[m]) for m in ("pq", "miou"))
            cells = [
                name,
                k,
                f"{b['pq']:.3f} → {a['pq']:.3f}",
                f"{a['pq'] - b['pq']:+.3f}",
                f"{b['miou']:.3f} → {a['miou']:.3f}",
                f"{a['miou'] - b['miou']:+.3f}",
                ref,
                gap,
                f"{last.get('coverage', float('nan')):.3f}",
                f"{last.get('precision', float('nan')):.3f}",
                timing,
            ]
            lines.append("| " + " | ".join(cells) + " |")
        s = row["source_after"]
        cells = [
            name,
            "source",
            f"{src['pq']:.3f} → {s['pq']:.3f}",
            f"{s['pq'] - src['pq']:+.3f}",
            f"{src['miou']:.3f} → {s['miou']:.3f}",
            f"{s['miou'] - src['miou']:+.3f}",
            "",
            "",
            "",
            "",
            "",
        ]
        lines.append("| " + " | ".join(cells) + " |")
    lines += [
        "",
        "Official mode, k = 1 + track, refine off for every model. A: the sequences adapted on "
        "(unlabelled to adapt); D: disjoint sequences of the same target; source: a held-out seed of the "
        "training styles and sensors, labelled by the model adapted to the row's target. reference: the "
        "source fine-tuned on A's ground truth with the same steps and learning rate; gap closed = "
        "(after − before) / (reference − before). coverage, precision: the last round's pseudo-labels "
        "(precision against the ground truth the log carries, never used for training). adapt: the whole "
        "`dsnet adapt` command (labelling, selection, training); CPU s: user + system seconds of it and "
        "its render workers; load: the shared 2-core machine's mean 1-minute load average meanwhile.",
    ]
    return "\n".join(lines) + "\n"


def _gap(before: float, after: float, reference: float) -> str:
    return f"{(after - before) / (reference - before):.2f}" if abs(reference - before) > 1e-9 else "–"


if __name__ == "__main__":
    main()
