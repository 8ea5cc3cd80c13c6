"""``dsnet label --scans 2`` SIGKILLed at 20 seeded moments spread over every stage, each run resumed
by the same command: the exported labels are byte-identical to an uninterrupted run's and the
stage and report tables are equal, 20 times out of 20.

Every kill is a real SIGKILL of a real ``dsnet label`` process started from an empty run folder;
the kill is triggered from outside, through the run store (tests/helpers/kill.py): when a chosen
stage of a chosen sequence has started, after its first block fragment, or at a random delay
inside the window that stage took in the uninterrupted run. Where the kill really landed is read
back from the store, and every stage must have been hit at least once.
"""

from __future__ import annotations

import json
import random
import subprocess
import time
from collections import Counter
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from storage.run import RunStore
from tests.flows.conftest import REPO, cli
from tests.helpers.kill import KillPoint, run_and_kill, where_stopped
from tests.helpers.tiny_log import write_tiny_log
from tests.model_helpers import make_checkpoint

STAGES = ("ingest", "align", "infer", "shift", "fuse", "stitch", "score")
SEQS = ("00", "01")
N_KILLS = 20
SEED = 2026
FAST_SHIFT = json.dumps({"kind": "dynamic_shift", "n_seeds": 300, "bandwidths": [0.2, 1.8, 3.4]})
# how the kill is placed inside a stage: at its start, after its first block, or at a random delay
# inside the time it took in the uninterrupted run
MODES = ("start", "first-block", "window")

# Columns that differ between two correct runs of the same log and so are left out of the table
# comparison: wall-clock timings (stage_timings: wall_s, block_s and the rates derived from them),
# the run's identity (score_run and label_run: run_id, created — a time stamp — and root, the run
# folder, which is another folder for every run here).
IGNORED = {
    "stage_timings": {"wall_s", "block_s", "items_per_s", "points_per_s"},
    "score_run": {"run_id", "created", "root"},
    "label_run": {"run_id", "created", "root"},
}


def _label_cmd(log: Path, ckpt: Path, root: Path) -> list[str]:
    return cli(
        "label", str(log), "--run", str(root), "--scans", "2", "--block-size", "1",
        "--checkpoint", str(ckpt), "--clusterer", FAST_SHIFT,
    )  # fmt: skip


def _export(root: Path, out: Path, env: dict[str, str]) -> dict[str, bytes]:
    res = subprocess.run(
        cli("export", str(root), "--out", str(out)), cwd=REPO, env=env, capture_output=True, text=True,
        timeout=120,
    )  # fmt: skip
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-2000:]
    files = {str(p.relative_to(out)): p.read_bytes() for p in sorted(out.rglob("*")) if p.is_file()}
    assert files, f"nothing exported from {root}"
    return files


def _tables(root: Path) -> dict[str, object]:
    """Every parquet table of the run (stage tables per sequence, report tables), ignored columns
    dropped."""
    out = {}
    for path in sorted((root / "tables").rglob("*.parquet")):
        rel = str(path.relative_to(root / "tables"))
        table = pq.read_table(path)
        drop = IGNORED.get(rel.split("/")[0], set()) & set(table.column_names)
        out[rel] = table.drop_columns(sorted(drop))
    return out


def _actions(root: Path) -> dict[tuple[str, str], str]:
    store = RunStore(root)
    run_id = store.read_run_config()["run_id"]
    record = store.root.read_json(f"runs/{run_id}.json")
    return {(r["sequence"], r["stage"]): r["action"] for r in record["summary"]}


def _plan(windows: dict[tuple[str, str], float]) -> list[KillPoint]:
    """20 kill points: every (stage, mode) pair once, shuffled, one left out; a random sequence."""
    rng = random.Random(SEED)
    pairs = [(stage, mode) for stage in STAGES for mode in MODES]
    rng.shuffle(pairs)
    points = []
    for stage, mode in pairs[:N_KILLS]:
        seq = rng.choice(SEQS)
        if mode == "start":
            points.append(KillPoint(stage, seq))
        elif mode == "first-block":
            points.append(KillPoint(stage, seq, blocks=1))
        else:
            points.append(KillPoint(stage, seq, delay_s=rng.uniform(0.0, windows[seq, stage])))
    return points


@pytest.mark.slow
@pytest.mark.timeout(1800)
def test_20_kills_over_every_stage_resume_identically(cli_env, tmp_path):
    env = {**cli_env, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    log = tmp_path / "log"
    for i, seq in enumerate(SEQS):
        write_tiny_log(log, frames=3, sequence=seq, seed=i)
    ckpt = make_checkpoint(tmp_path / "ckpt", seed=0)

    t_start = time.monotonic()
    ref_root = tmp_path / "ref"
    res = subprocess.run(
        _label_cmd(log, ckpt, ref_root), cwd=REPO, env=env, capture_output=True, text=True, timeout=600
    )
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    ref_files = _export(ref_root, tmp_path / "ref-export", env)
    ref_tables = _tables(ref_root)
    assert {f"frames/sequence={s}/part-0.parquet" for s in SEQS} <= set(ref_tables)
    assert "score_run/part-0.parquet" in ref_tables
    ref_store = RunStore(ref_root)
    windows = {  # seconds each stage took in the uninterrupted run
        (seq, stage): ref_store.read_manifest(seq, stage).timings["wall_s"]
        for seq in SEQS
        for stage in STAGES
    }

    landed: Counter[str] = Counter()
    identical = 0
    lines = []
    for k, point in enumerate(_plan(windows)):
        root = tmp_path / f"kill-{k:02d}"
        cmd = _label_cmd(log, ckpt, root)
        result = run_and_kill(cmd, env, point, root=str(root), cwd=str(REPO), timeout=600)
        assert result.killed, f"kill {k} ({point.describe()}): the run ended first:\n{result.output[-3000:]}"
        assert result.returncode == -9, result.output[-3000:]
        stage, detail = where_stopped(str(root), SEQS, STAGES)
        landed[stage] += 1

        resumed = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True, timeout=600)
        assert resumed.returncode == 0, (
            f"kill {k} ({point.describe()}, landed in {stage}: {detail}): resume failed\n"
            + resumed.stdout[-3000:]
            + resumed.stderr[-3000:]
        )
        acts = _actions(root)
        if stage in STAGES:  # the stages finished before the kill are not redone
            for before in STAGES[: STAGES.index(stage)]:
                assert all(acts[s, before] == "skip" for s in SEQS), (k, stage, acts)
        files = _export(root, tmp_path / f"export-{k:02d}", env)
        tables = _tables(root)
        bad_files = sorted(n for n in files.keys() | ref_files.keys() if files.get(n) != ref_files.get(n))
        bad_tables = sorted(
            n for n in tables.keys() | ref_tables.keys()
            if n not in tables or n not in ref_tables or not tables[n].equals(ref_tables[n])
        )  # fmt: skip
        identical += not bad_files and not bad_tables
        verdict = "identical" if not bad_files and not bad_tables else f"DIFFERENT {bad_files} {bad_tables}"
        lines.append(f"kill {k:2d}: {point.describe():45s} landed in {stage:8s} [{detail}] resumed {verdict}")
        print(lines[-1], flush=True)

    per_stage = {s: landed[s] for s in STAGES} | {s: n for s, n in landed.items() if s not in STAGES}
    summary = f"kills: {identical}/{N_KILLS} identical; per stage: {per_stage}"
    print(f"{summary}; {time.monotonic() - t_start:.0f} s")
    assert identical == N_KILLS, summary + "\n" + "\n".join(lines)
    assert all(landed[s] >= 1 for s in STAGES), summary + "\n" + "\n".join(lines)
