"""``dsnet train`` as a real subprocess: SIGKILL mid-training, then --resume continues."""

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from tests.helpers.tiny_log import write_tiny_log

REPO = Path(__file__).resolve().parents[2]


def cli(*args):
    env = {**os.environ, "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1"}
    return [sys.executable, "-m", "flows.cli", "train", "dsnet", *map(str, args)], env


def epochs_done(ckpt: Path) -> int:
    try:
        return json.loads((ckpt / "card.json").read_text())["epochs"].get("semantic", 0)
    except (FileNotFoundError, json.JSONDecodeError):
        return 0


@pytest.mark.slow
@pytest.mark.timeout(900)
def test_sigkill_then_resume(tmp_path):
    log = write_tiny_log(tmp_path / "log", frames=2)
    ckpt = tmp_path / "ckpt"
    common = ["--out", ckpt, "--stage", "semantic", "--epochs", "semantic=4", "--grid", "24,32,8"]
    common += ["--no-augment", "--lr", "0.01"]
    cmd, env = cli(log, *common)
    proc = subprocess.Popen(cmd, cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    deadline = time.time() + 600
    while epochs_done(ckpt) < 1 and proc.poll() is None and time.time() < deadline:
        time.sleep(0.2)
    assert proc.poll() is None, proc.communicate()[1].decode()[-2000:]
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert proc.returncode == -signal.SIGKILL
    killed_card = json.loads((ckpt / "card.json").read_text())
    done = killed_card["epochs"]["semantic"]
    assert 1 <= done < 4

    # without --resume the existing checkpoint is refused
    cmd, env = cli(log, *common)
    refused = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True)
    assert refused.returncode == 2 and "already holds a checkpoint: pass --resume" in refused.stderr

    cmd, env = cli(log, *common, "--resume")
    resumed = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True, timeout=600)
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    assert "wrote checkpoint" in resumed.stdout and f"resuming from {ckpt}" in resumed.stderr
    card = json.loads((ckpt / "card.json").read_text())
    assert card["epochs"] == {"semantic": 4}
    # the epochs before the kill are kept as they were; training continued after them
    assert card["metrics"][:done] == killed_card["metrics"]
    assert [m["epoch"] for m in card["metrics"]] == [1, 2, 3, 4]
    rows = (ckpt / "metrics.csv").read_text().splitlines()
    assert len(rows) == 5


def _train_files(ckpt: Path) -> dict[str, bytes]:
    return {name: (ckpt / name).read_bytes() for name in ("model.safetensors", "shift.safetensors")}


def _epochs(card_file: Path) -> dict[str, int] | None:
    try:
        return json.loads(card_file.read_text())["epochs"]
    except (FileNotFoundError, json.JSONDecodeError, KeyError):
        return None


def committed_epochs(ckpt: Path) -> int | None:
    """Epochs done over all stages, as a resume will find them: a committed but not yet moved
    epoch (``.pending/COMMIT``, rolled forward on resume) counts. None while unreadable."""
    pending = ckpt / ".pending"
    if (pending / "COMMIT").is_file() and (pending / "card.json").is_file():
        epochs = _epochs(pending / "card.json")
    elif not (ckpt / "card.json").exists():
        return 0
    else:
        epochs = _epochs(ckpt / "card.json")
    return None if epochs is None else sum(epochs.values())


@pytest.mark.slow
@pytest.mark.timeout(1800)
def test_kills_at_random_moments_resume_to_bit_identical_weights(tmp_path):
    """Three SIGKILLs at seeded random moments, one in each training stage (semantic, offset,
    shift), each followed by --resume: the final weights equal an uninterrupted run's, byte for byte.

    Each kill is planned as (epoch, fraction of that epoch) on the uninterrupted run's timeline:
    the process is signalled once the checkpoint shows that epoch's predecessors committed, that
    fraction of the epoch's measured time later. Every planned kill must happen (the process was
    still running) and land inside its planned epoch (the checkpoint afterwards holds exactly the
    epochs before it), so the three kills really are one per stage."""
    import random

    from tests.helpers.kill import KillPoint, run_and_kill

    log = write_tiny_log(tmp_path / "log", frames=2)
    schedule = {"semantic": 3, "offset": 2, "shift": 2}
    common = ["--stage", "all", "--epochs", ",".join(f"{k}={v}" for k, v in schedule.items())]
    common += ["--grid", "24,32,8", "--lr", "0.01"]
    straight = tmp_path / "straight"
    cmd, env = cli(log, "--out", straight, *common)
    # the uninterrupted run, with the moment each epoch was committed
    t0 = time.monotonic()
    proc = subprocess.Popen(cmd, cwd=REPO, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    stderr = []
    reader = threading.Thread(target=lambda: stderr.append(proc.stderr.read()))
    reader.start()
    committed = [0.0]  # committed[g]: seconds from the start until g epochs were committed
    while proc.poll() is None and time.monotonic() - t0 < 900:
        n = committed_epochs(straight)
        if n is not None and n >= len(committed):
            committed += [time.monotonic() - t0] * (n - len(committed) + 1)
        time.sleep(0.02)
    proc.wait(timeout=60)
    reader.join(timeout=60)
    assert proc.returncode == 0, stderr[0].decode()[-2000:]
    total = sum(schedule.values())
    if len(committed) <= total:
        committed += [time.monotonic() - t0] * (total + 1 - len(committed))

    # one kill per stage, in a random epoch of it, at a random point of that epoch (not its very
    # end: the killed run must not commit the epoch before the signal lands)
    rng = random.Random(20)
    plan, first = [], 0
    for stage, n in schedule.items():
        g = first + rng.randrange(n)  # the epoch (over all stages) the kill lands in
        plan.append((stage, g, rng.uniform(0.1, 0.6), range(first, first + n)))
        first += n
    ckpt = tmp_path / "killed"
    for attempt, (stage, g, frac, epochs) in enumerate(plan):
        cmd, env = cli(log, "--out", ckpt, *common, *(["--resume"] if attempt else []))
        # epoch 0's window starts with the process (imports and data loading included)
        delay = frac * (committed[g + 1] - committed[g])
        point = KillPoint(delay_s=delay)

        def reached(g=g) -> bool:
            return committed_epochs(ckpt) == g

        res = run_and_kill(cmd, env, point, cwd=str(REPO), timeout=600, when=reached)
        where = f"kill {attempt} planned in {stage} epoch {g + 1} of {total}, {delay:.1f} s in"
        assert res.killed, f"{where}: the run ended first\n{res.output[-2000:]}"
        assert res.returncode == -signal.SIGKILL, f"{where}: {res.output[-2000:]}"
        # on a loaded machine an epoch can end before the planned moment: still inside the stage
        landed = committed_epochs(ckpt)
        assert landed in epochs, f"{where}: landed after {landed} epochs, outside {stage}"
    cmd, env = cli(log, "--out", ckpt, *common, "--resume")
    resumed = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True, timeout=900)
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    assert json.loads((ckpt / "card.json").read_text())["epochs"] == schedule
    assert _train_files(ckpt) == _train_files(straight)
