"""Bad numeric options of ``dsnet label`` are refused by name before anything runs."""

from __future__ import annotations

import pytest
from typer.testing import CliRunner

from flows.cli import app


@pytest.mark.parametrize(
    ("option", "value"),
    [("--block-size", "0"), ("--block-size", "-3"), ("--stride", "0"), ("--scans", "0")],
)
def test_label_refuses_non_positive_sizes(tmp_path, option, value):
    args = ["label", str(tmp_path), "--run", str(tmp_path / "run"), option, value]
    res = CliRunner().invoke(app, args, env={"COLUMNS": "250"})
    assert res.exit_code == 2
    assert option in res.output and "greater than or equal to 1" in res.output
    assert not (tmp_path / "run").exists()


def test_model_options_reach_the_infer_stage_config():
    from tasks.methods import stage_configs

    assert "infer" not in stage_configs(scans=1)  # the plain path records nothing
    assert stage_configs(scans=1, tta=4, tta_flip=True, device="cuda")["infer"] == {
        "device": "cuda",
        "tta": 4,
        "tta_flip": True,
    }
    res = CliRunner().invoke(app, ["label", ".", "--run", "y", "--tta", "0"], env={"COLUMNS": "250"})
    assert res.exit_code == 2 and "--tta" in res.output


def test_a_local_dask_cluster_listens_on_loopback_only():
    from flows.label import task_runner

    runner = task_runner(workers=2)  # not started: its settings are what matters
    assert runner.cluster_kwargs["host"] == "127.0.0.1"
    assert runner.cluster_kwargs["dashboard_address"].startswith("127.0.0.1:")
