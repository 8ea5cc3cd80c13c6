"""``make gpu-check``: everything a GPU session measures, in one command and one table.

On a machine with a CUDA torch and no package registry (see gpu/gpu_wheels.py for what it has):

1. installs the wheels of ``--wheels`` (made beforehand by ``make gpu-wheels``) into a temporary
   target and puts it first on the path; the machine's torch is not touched;
2. runs every ``gpu``-marked test (tests/gpu: CUDA equals CPU for inference, sparse convolution,
   dynamic shifting and training in each AMP mode), one row per test;
3. runs gpu/bench_gpu.py (frames/s at k = 1 and 2, training steps with and without AMP and their
   peak memory, the label stages per frame) with what is left of ``--budget``;
4. prints one table (and writes it, with the machine and every bench figure, as one JSON file to
   ``--out`` if given: a device run returns at most 8 files).

``--device cpu`` is the smoke mode for a machine without a GPU: the tests run with the CPU on
both sides (they prove they run, not that CUDA equals CPU) and the bench takes the ``tiny``
preset on 4 frames. Exit status 1 when a test or the bench failed. Only the standard library is
imported here; the work runs in child processes.

Run: ``python3 gpu/gpu_check.py [--device cuda] [--budget 450] [--out FILE.json]``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
import xml.etree.ElementTree as ET
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from gpu_wheels import DEFAULT_WHEELS, ROOT, WheelError, activate

ENV_PROBE = """
import json, platform, torch
cuda = torch.cuda.is_available()
print(json.dumps({
    "python": platform.python_version(),
    "torch": torch.__version__,
    "cuda": torch.version.cuda,
    "gpu": torch.cuda.get_device_name(0) if cuda else None,
    "gpu_mib": torch.cuda.get_device_properties(0).total_memory // 2**20 if cuda else None,
    "cpus": __import__("os").cpu_count(),
}))
"""
IMPORTS = "import zarr, numcodecs, pydantic, pytest, pytest_timeout, dsnet_core, storage, tasks"


class Table:
    """Rows of (part, what, result, detail), printed as one Markdown table."""

    def __init__(self) -> None:
        self.rows: list[tuple[str, str, str, str]] = []
        self.failed = False

    def add(self, part: str, what: str, result: str, detail: str = "", failed: bool = False) -> None:
        self.rows.append((part, what, result, detail))
        self.failed |= failed

    def render(self) -> str:
        head = ("part", "what", "result", "detail")
        widths = [max(len(r[i]) for r in [head, *self.rows]) for i in range(4)]
        line = lambda r: "| " + " | ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)) + " |"  # noqa: E731
        sep = "|" + "|".join("-" * (w + 2) for w in widths) + "|"
        return "\n".join([line(head), sep, *(line(r) for r in self.rows)])


def run(cmd: list[str], timeout: float, env: dict | None = None) -> tuple[int, str, float]:
    """(exit status, the last 4000 characters of stdout + stderr, seconds); status 124 on timeout."""
    t0 = time.perf_counter()
    try:
        done = subprocess.run(
            cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=max(timeout, 1.0)
        )
        code, text = done.returncode, done.stdout + done.stderr
    except subprocess.TimeoutExpired as exc:
        out = (exc.stdout or b"") + (exc.stderr or b"")
        code, text = 124, out.decode(errors="replace") if isinstance(out, bytes) else out
    return code, text[-4000:], time.perf_counter() - t0


def junit_rows(path: Path) -> list[tuple[str, str, float, str]]:
    """(test id, passed | failed | error | skipped, seconds, message) per test case of a JUnit file."""
    rows = []
    for case in ET.parse(path).getroot().iter("testcase"):
        name = f"{case.get('classname', '').rsplit('.', 1)[-1]}::{case.get('name')}"
        result, message = "passed", ""
        for tag in ("failure", "error", "skipped"):
            node = case.find(tag)
            if node is not None:
                result = {"failure": "failed"}.get(tag, tag)
                message = (node.get("message") or "").splitlines()[0][:100] if node.get("message") else ""
                break
        rows.append((name, result, float(case.get("time", 0.0)), message))
    return rows


def check_tests(table: Table, args: argparse.Namespace, env: dict, timeout: float, tmp: Path) -> None:
    report = tmp / "tests.xml"
    cmd = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-p", "pytest_timeout"]
    cmd += ["-m", "gpu", "tests/gpu", f"--junitxml={report}", "-o", f"timeout={int(max(timeout, 30))}"]
    # the machine's own pytest plugins (xdist, cov, benchmark, ...) were built for its pytest, not
    # for the one the wheels put first: load none of them
    test_env = {**env, "PYTEST_DISABLE_PLUGIN_AUTOLOAD": "1"}
    if args.device == "cpu":
        test_env["DSNET_GPU_TESTS_ON_CPU"] = "1"
    code, text, secs = run(cmd, timeout, test_env)
    rows = junit_rows(report) if report.is_file() else []
    for name, result, t, message in rows:
        table.add("test", name, result, f"{t:.1f} s {message}".strip(), failed=result in ("failed", "error"))
    if code not in (0, 5) or not rows:
        table.add("test", "pytest -m gpu tests/gpu", f"exit {code}", f"{secs:.0f} s", failed=True)
        print(f"--- pytest output (tail) ---\n{text}", file=sys.stderr)


def check_bench(table: Table, args: argparse.Namespace, env: dict, timeout: float, tmp: Path) -> dict:
    out = tmp / "bench.json"
    cmd = [sys.executable, "gpu/bench_gpu.py", "--device", args.device, "--preset", args.preset]
    cmd += ["--frames", str(args.frames), "--repeats", str(args.repeats), "--json", str(out)]
    cmd += ["--budget", str(max(timeout - 90, 0))]  # the last part must still fit
    code, text, secs = run(cmd, timeout, env)
    res = json.loads(out.read_text()) if out.is_file() else {}
    pre = f"{res.get('preset', args.preset)}"
    for k, r in res.get("forward", {}).items():
        table.add(
            "bench",
            f"frames/s {pre} {k}",
            f"{r['frames_per_s']:.2f}",
            f"network {r['network_s'] * 1e3:.0f} ms + shift/cluster {r['shift_s'] * 1e3:.0f} ms per volume "
            f"({r['points']} pts, {r['thing_points']} thing)",
        )
    for amp, r in res.get("train", {}).items():
        table.add(
            "bench",
            f"train step {pre} batch 2 amp {amp}",
            f"{r['step_s']:.3f} s",
            f"peak {r['peak_of']} {r['peak_mib']:.0f} MiB (median of {r['steps']})",
        )
    if "stages" in res:
        per = res["stages"]
        table.add(
            "bench",
            f"label stages {pre} k1 s/frame",
            f"{sum(per.values()):.3f}",
            " ".join(f"{s} {v:.3f}" for s, v in per.items()),
        )
    for name in res.get("skipped", []):
        table.add("bench", name, "skipped", "past the time budget", failed=True)
    if code != 0:
        table.add("bench", "gpu/bench_gpu.py", f"exit {code}", f"{secs:.0f} s", failed=True)
        print(f"--- bench output (tail) ---\n{text}", file=sys.stderr)
    return res


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cuda", choices=("cuda", "cpu"))
    ap.add_argument("--wheels", type=Path, default=DEFAULT_WHEELS)
    ap.add_argument("--budget", type=float, default=450.0, help="seconds for everything (8 min with margin)")
    ap.add_argument("--preset", default=None, help="bench width (default paper; tiny with --device cpu)")
    ap.add_argument("--frames", type=int, default=None, help="bench log frames (default 6; 4 on cpu)")
    ap.add_argument("--repeats", type=int, default=None, help="timed repeats (default 5; 1 on cpu)")
    ap.add_argument("--tests-share", type=float, default=0.35, help="fraction of the budget for tests")
    ap.add_argument("--out", type=Path, default=None, help="JSON file for the table and every figure")
    args = ap.parse_args()
    cpu = args.device == "cpu"
    args.preset = args.preset or ("tiny" if cpu else "paper")
    args.frames = args.frames or (4 if cpu else 6)
    args.repeats = args.repeats or (1 if cpu else 5)
    start = time.perf_counter()
    left = lambda: args.budget - (time.perf_counter() - start)  # noqa: E731
    table = Table()
    try:
        site = activate(args.wheels)
    except (WheelError, subprocess.CalledProcessError) as exc:
        sys.exit(f"error: {exc}")
    table.add(
        "setup", "wheels", "installed" if site else "none", f"{site} ({time.perf_counter() - start:.0f} s)"
    )
    env = dict(os.environ)
    code, text, _ = run([sys.executable, "-c", ENV_PROBE], 120, env)
    info = json.loads(text.strip().splitlines()[-1]) if code == 0 else {}
    table.add(
        "setup",
        "machine",
        info.get("gpu") or "no CUDA device",
        f"Python {info.get('python')}, torch {info.get('torch')} (CUDA {info.get('cuda')}), "
        f"{info.get('gpu_mib')} MiB, {info.get('cpus')} CPUs",
        failed=code != 0 or (not cpu and not info.get("gpu")),
    )
    code, text, _ = run([sys.executable, "-c", IMPORTS], 120, env)
    table.add(
        "setup",
        "imports",
        "ok" if code == 0 else "failed",
        "" if code == 0 else text.strip()[-100:],
        code != 0,
    )
    if table.failed:
        print(table.render())
        sys.exit(1)
    with tempfile.TemporaryDirectory(prefix="gpu-check-") as tmp:
        check_tests(table, args, env, left() * args.tests_share, Path(tmp))
        bench = check_bench(table, args, env, left() - 10, Path(tmp))
    total = time.perf_counter() - start
    table.add(
        "total", "wall time", f"{total:.0f} s", f"budget {args.budget:.0f} s", failed=total > args.budget
    )
    text = table.render()
    print(text)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        record = {"table": text.splitlines(), "rows": table.rows, "machine": info, "bench": bench}
        args.out.write_text(json.dumps(record, indent=2))
    sys.exit(1 if table.failed else 0)


if __name__ == "__main__":
    main()
