"""Issue 40: `train` and `adapt` refused bad options in 2–4.4 s (12 s for ``adapt --clusterer bogus``
on a loaded machine) where `label` took 0.2–0.7 s: torch and the trainers were imported first. Each
refusal here must come before torch is imported at all (what made them slow; no wall-clock assert)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from tests.helpers.tiny_log import write_tiny_log

REPO = Path(__file__).resolve().parents[2]
PROBE = """
import sys
from typer.testing import CliRunner
from flows.cli import app
res = CliRunner().invoke(app, sys.argv[1:])
print("exit", res.exit_code)
print("torch imported" if "torch" in sys.modules else "torch not imported")
print(res.output)
"""


@pytest.fixture(scope="module")
def log(tmp_path_factory):
    return write_tiny_log(tmp_path_factory.mktemp("log") / "a", frames=2, n=200)


CASES = {
    "adapt LOG --out OUT --clusterer bogus": "--clusterer 'bogus'",
    "adapt LOG --out OUT --steps 1": "steps ≥ epochs",
    "adapt NOWHERE --out OUT": "NOWHERE: no such file or folder",
    "adapt LOG --out OUT --from NOWHERE": "no model card",
    "adapt LOG --out AFILE": "AFILE: is a file",
    "train dsnet LOG --out OUT --epochs bogus=1": "unknown stage 'bogus'",
    "train dsnet LOG --out OUT --preset bogus": "unknown model preset",
    "train dsnet LOG --out OUT --stage offset --epochs semantic=1": "trains 0 epochs",
    "train dsnet NOWHERE --out OUT": "NOWHERE: no such file or folder",
    "train dsnet LOG --out OUT --init-from NOWHERE": "no model card",
    "train dsnet LOG --out AFILE": "AFILE: is a file",
    "train most LOG --out OUT --epochs bogus=1": "unknown stage 'bogus'",
    "train dpls LOG --out OUT --epochs x": "--epochs 'x'",
}
"""Each command line (LOG a tiny log, OUT a new folder, NOWHERE a missing path, AFILE a file) and
what its one error line says."""


@pytest.mark.parametrize("case", sorted(CASES))
def test_a_bad_train_or_adapt_option_is_refused_before_torch_is_imported(case, log, tmp_path):
    args, message = case.split(), CASES[case]
    (tmp_path / "AFILE").write_text("x")
    where = {"LOG": str(log), "OUT": str(tmp_path / "out"), "NOWHERE": str(tmp_path / "NOWHERE")}
    where["AFILE"] = str(tmp_path / "AFILE")
    args = [where.get(a, a) for a in args]
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    res = subprocess.run(
        [sys.executable, "-c", PROBE, *args], cwd=REPO, env=env, capture_output=True, text=True, timeout=120
    )
    lines = res.stdout.splitlines()
    assert lines[:2] == ["exit 2", "torch not imported"], res.stdout[-2000:] + res.stderr[-2000:]
    errors = [ln for ln in lines[2:] if ln.strip()]
    assert len(errors) == 1 and errors[0].startswith("error: ")
    assert message.replace("NOWHERE", where["NOWHERE"]).replace("AFILE", where["AFILE"]) in errors[0]
    assert not (tmp_path / "out").exists()
