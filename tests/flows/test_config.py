"""One way to configure (#39 item 1): each method's label settings declared once (its ``Settings``
model) are the flags of ``label``, ``serve`` and ``demo``; a ``--config`` YAML and ``--set`` dotted
overrides resolve in layers (defaults < file < flags given < --set), each checked into one line
naming the key before any server starts; ``dsnet config dump`` prints the defaults the file takes;
the run folder keeps the resolved ``config.yaml``, which reproduces the run."""

from __future__ import annotations

import pytest
import typer
import yaml
from typer.testing import CliRunner

from flows.cli import app
from flows.config import default_config, read_config, resolve, resolved_config
from tasks.methods import METHODS, LabelSettings, get_method
from tests.logs import make_log

SAMPLES = {  # a value other than the default of every setting a bundled method takes
    "scans": [1, 4],
    "stride": [1],
    "checkpoint": ["/ckpt"],
    "clusterer": ["dbscan", '{"kind": "meanshift", "bandwidth": 1.5}'],
    "estimate_poses": [True],
    "max_points": [5],
    "device": ["cuda:1"],
    "tta": [3],
    "tta_flip": [True],
    "equivariant": [4],
    "match": ["both"],
    "semantic_prior": ["/prior"],
    "temporal": ["track"],
    "refine": [False],
}


def _changed(a: dict, b: dict) -> set[str]:
    keys = {(s, k) for s in a.keys() | b.keys() for k in a.get(s, {}).keys() | b.get(s, {}).keys()}
    return {f"{s}.{k}" for s, k in keys if a.get(s, {}).get(k, "absent") != b.get(s, {}).get(k, "absent")}


@pytest.mark.parametrize("name", list(METHODS))
def test_a_setting_writes_only_the_stage_keys_its_method_declares(name):
    """``stage_keys`` is what lets a flag override a config file: it must be the truth."""
    method = get_method(name)
    base = method.stage_settings(method.Settings())
    assert set(SAMPLES) >= method.settings - {"prior_label_map"}
    for field in method.Settings.model_fields:
        for value in SAMPLES.get(field, []):
            given = {field: value, **({"semantic_prior": "/p"} if field == "prior_label_map" else {})}
            stages = method.stage_settings(LabelSettings(**given))
            owned = {k for f in given for k in method.stage_keys.get(f, ())}
            assert _changed(base, stages) <= owned, (field, value)


@pytest.mark.parametrize("name", list(METHODS))
def test_without_a_file_the_flags_resolve_to_what_the_method_makes_of_them(name):
    """The layered resolution gives, for flags alone, the very stage configs and method options the
    method makes of them (so runs without --config keep their fingerprints)."""
    method = get_method(name)
    for field in method.Settings.model_fields:
        for value in SAMPLES.get(field, []):
            given = {field: value}
            typed = method.settings_of(LabelSettings(**given))
            config = resolve(method=name, settings=given)
            assert config.stages == {k: v for k, v in method.stage_settings(typed).items() if v}, given
            assert config.method_options == method.options(typed), given


def test_flags_given_override_the_file_and_set_overrides_both():
    file = {
        "stages": {"align": {"scans": 1}, "infer": {"tta": 3, "device": "cuda"}},
        "options": {"block_size": 7},
    }
    assert resolve(file).stages == {"align": {"scans": 1}, "infer": {"tta": 3, "device": "cuda"}}
    # --scans 2 is the default, yet given: it wins over the file; --tta 1 takes the file's tta back
    config = resolve(file, settings={"scans": 2, "tta": 1}, given={"options": {"lock_wait_s": 2.0}})
    assert config.stages == {"align": {"scans": 2}, "infer": {"device": "cuda"}}
    assert (config.options.block_size, config.options.lock_wait_s) == (7, 2.0)
    config = resolve(
        file,
        settings={"tta": 2},
        sets=[
            "infer.tta=4",
            "shift.clusterer=meanshift",
            "options.block_size=9",
            "method_options.temporal=track",
        ],
    )
    assert config.stages["infer"]["tta"] == 4 and config.stages["shift"] == {"clusterer": "meanshift"}
    assert config.options.block_size == 9 and config.method_options == {"temporal": "track"}
    assert (
        get_method()
        .pipeline(config.method_options, config.stages)["shift"]
        .Config.model_validate(config.stages["shift"])
        .clusterer.kind
        == "meanshift"
    )  # a kind's name alone is that kind with its defaults
    assert resolve(sets=["method=most"]).method == "most"


@pytest.fixture(scope="module")
def log(tmp_path_factory):
    return make_log(tmp_path_factory.mktemp("log"), ("00",), n_frames=3, n_ground=300)


def _refused(args: list[str], monkeypatch) -> str:
    """The one ``error:`` line of a command refused before it executes anything."""
    import flows.commands.label as label_command

    def no_run(*a, **k):
        raise AssertionError("reached execute: services checked, a server would start")

    monkeypatch.setattr(label_command, "execute", no_run)
    res = CliRunner().invoke(app, args, env={"COLUMNS": "250"})
    assert res.exit_code == 2, (res.output, res.exception)
    lines = res.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), res.output
    return lines[0].removeprefix("error: ")


REFUSED = [  # (config file text or None, --set entries, the error line; FILE: the file's path)
    (None, ["infer.ttx=2"], "--set infer.ttx=2: not a setting of stage infer (its settings: checkpoint, "
     "device, batch, tta, tta_flip, equivariant, argmax, match)"),
    (None, ["infer.tta=0"], "--set infer.tta=0: Input should be greater than or equal to 1"),
    (None, ["inferr.tta=2"], "--set inferr.tta=2: no stage 'inferr' in method dsnet (stages: ingest, "
     "align, infer, shift, fuse, stitch, refine, score)"),
    (None, ["shift.clusterer=bogus"], "--set shift.clusterer=bogus: not a kind it takes "
     "(expected: 'dynamic_shift', 'meanshift', 'dbscan', 'hdbscan', 'bfs')"),
    (None, ["options.block_size=0"], "--set options.block_size=0: Input should be greater than or equal "
     "to 1"),
    (None, ["infer"], "--set 'infer': expected KEY=VALUE with a dotted key (e.g. infer.tta=2)"),
    (None, ["infer=2"], "--set infer=2: expected STAGE.KEY=VALUE (e.g. infer.tta=2)"),
    ("stagez: {}\n", [], "--config FILE: unknown key 'stagez' (keys: method, method_options, format, "
     "reader_options, sequences, stages, options)"),
    ("stages: {infer: {tta: 0}}\n", [], "--config FILE: infer.tta 0: Input should be greater than or equal "
     "to 1"),
    ("stages: {align: {scans: x}}\n", [], "--config FILE: align.scans 'x': Input should be a valid integer, "
     "unable to parse string as an integer"),
    ("options: {on_error: maybe}\n", [], "--config FILE: options.on_error 'maybe': Input should be 'fail' "
     "or 'skip'"),
    ("method_options: {temporal: sideways}\n", [], "--config FILE: method_options: unknown temporal "
     "association 'sideways'; choose one of ['stitch', 'track']"),
    ("[1, 2]\n", [], "--config FILE: expected a mapping of method, method_options, format, reader_options, "
     "sequences, stages, options"),
    ("method: most\nstages: {infer: {tta: 2}}\n", [], "--config FILE: infer: no stage 'infer' in method most "
     "(stages: ingest, align, most, track, refine, score)"),
]  # fmt: skip


@pytest.mark.parametrize(
    ("text", "sets", "want"), REFUSED, ids=[w.split(":")[0] + str(i) for i, (_, _, w) in enumerate(REFUSED)]
)
def test_bad_keys_and_values_are_one_line_before_anything_runs(log, tmp_path, monkeypatch, text, sets, want):
    run = tmp_path / "run"
    args = ["label", str(log), "--run", str(run)]
    path = tmp_path / "bad.yaml"
    if text is not None:
        path.write_text(text)
        args += ["--config", str(path)]
    for entry in sets:
        args += ["--set", entry]
    assert _refused(args, monkeypatch) == want.replace("FILE", str(path))
    assert not run.exists()


def test_a_flag_the_method_lacks_is_refused_by_its_flag_even_with_a_file(log, tmp_path, monkeypatch):
    path = tmp_path / "c.yaml"
    path.write_text("method: most\n")
    line = _refused(
        ["label", str(log), "--run", str(tmp_path / "r"), "--config", str(path), "--tta", "2"], monkeypatch
    )
    assert line.startswith("--tta: not a setting of method most")


@pytest.mark.parametrize("name", list(METHODS))
def test_config_dump_round_trips(name, log, tmp_path):
    """``config dump`` → ``--config`` resolves to the same run config as the defaults alone."""
    res = CliRunner().invoke(app, ["config", "dump", "--method", name])
    assert res.exit_code == 0, res.output
    path = tmp_path / "dump.yaml"
    path.write_text(res.output)
    dumped = yaml.safe_load(res.output)
    assert dumped == default_config(name).model_dump(mode="json")
    pipeline = get_method(name).pipeline(dumped["method_options"], dumped["stages"])
    assert list(dumped["stages"]) == pipeline.names()  # every stage, in order
    from_file = resolve(read_config(path))
    plain = resolve(method=name)
    a, b = (c.request(data=str(log), root=str(tmp_path / "r")) for c in (from_file, plain))
    pa, pb = a.pipeline(), b.pipeline()
    assert pa.names() == pb.names() and pa.options == pb.options
    assert resolved_config(a, pa, "semantickitti", ["00"]) == resolved_config(b, pb, "semantickitti", ["00"])
    saved = resolved_config(a, pa, "semantickitti", ["00"])  # what the run folder keeps
    again = resolve(yaml.safe_load(saved.to_yaml())).request(data=str(log), root=str(tmp_path / "r"))
    assert resolved_config(again, again.pipeline(), "semantickitti", ["00"]) == saved


def _params(command: str) -> set[str]:
    group = typer.main.get_command(app)
    return {opt for p in group.commands[command].params for opt in p.opts}


def test_serve_takes_every_option_label_takes_from_the_same_models():
    label, serve, demo = _params("label"), _params("serve"), _params("demo")
    settings = {"--" + n.replace("_", "-") for m in METHODS.values() for n in m.Settings.model_fields}
    assert settings <= label and settings <= serve
    assert {"--tta", "--tta-flip", "--equivariant", "--config", "--set", "--method"} <= serve
    assert {"--" + n.replace("_", "-") for n in get_method().Settings.model_fields} <= demo
    run_only = {"--sequences", "--from-stage", "--force", "--on-error", "--block-size", "--lock-wait",
                "--debug", "--workers", "--dask-address", "--run", "data"}  # fmt: skip
    assert label - run_only <= serve


def test_serve_refuses_a_bad_set_before_it_asks_for_a_server(tmp_path, monkeypatch):
    monkeypatch.delenv("PREFECT_API_URL", raising=False)
    res = CliRunner().invoke(
        app, ["serve", "--watch", str(tmp_path), "--runs", str(tmp_path / "r"), "--set", "infer.tta=0"]
    )
    assert res.exit_code == 2
    assert res.output.strip() == "error: --set infer.tta=0: Input should be greater than or equal to 1"


FAST_SHIFT = "{kind: dynamic_shift, n_seeds: 300, bandwidths: [0.2, 1.8, 3.4]}"


def test_label_with_config_and_set_then_reproduce_the_run_from_its_saved_config(
    prefect_api_url, synth_log, tmp_path
):
    import numpy as np

    from flows.export import export_semantickitti
    from storage.run import RunStore
    from tests.model_helpers import make_checkpoint

    ckpt = make_checkpoint(tmp_path / "ckpt")
    config = tmp_path / "run.yaml"
    config.write_text(f"sequences: ['00']\nstages:\n  align: {{scans: 1}}\n  infer: {{checkpoint: {ckpt}}}\n")
    first, second = tmp_path / "r1", tmp_path / "r2"
    env = {"PREFECT_API_URL": prefect_api_url, "COLUMNS": "200"}
    args = ["label", str(synth_log), "--run", str(first), "--config", str(config), "--no-refine"]
    args += ["--set", "infer.tta=2", "--set", f"shift.clusterer={FAST_SHIFT}"]
    res = CliRunner().invoke(app, args, env=env)
    assert res.exit_code == 0, res.output
    saved = yaml.safe_load((first / "config.yaml").read_text())
    assert saved["stages"]["infer"]["tta"] == 2 and saved["stages"]["infer"]["checkpoint"] == str(ckpt)
    assert saved["stages"]["shift"]["clusterer"]["n_seeds"] == 300
    assert saved["stages"]["align"]["scans"] == 1 and saved["sequences"] == ["00"]
    assert saved["method_options"] == {"temporal": "track", "refine": False}
    assert saved["format"] == "semantickitti" and saved["stages"]["ingest"]["grid"] is not None

    res = CliRunner().invoke(
        app, ["label", str(synth_log), "--run", str(second), "--config", str(first / "config.yaml")], env=env
    )
    assert res.exit_code == 0, res.output
    assert (second / "config.yaml").read_text() == (first / "config.yaml").read_text()
    a, b = RunStore(first), RunStore(second)
    labels = a.read_manifest("00", "track")
    assert labels.fingerprint == b.read_manifest("00", "track").fingerprint
    for run, out in ((first, tmp_path / "p1"), (second, tmp_path / "p2")):
        assert export_semantickitti(str(run), out).frames == {"00": 6}
    for f in sorted((tmp_path / "p1" / "sequences" / "00" / "predictions").iterdir()):
        other = tmp_path / "p2" / "sequences" / "00" / "predictions" / f.name
        assert np.array_equal(np.fromfile(f, np.uint32), np.fromfile(other, np.uint32)), f.name
