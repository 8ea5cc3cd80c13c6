"""``dsnet train dsnet --stream``: every (stage, epoch) trains on its own window of never-seen generated
sequences, background rendering returns the serial samples, and a resumed run is bit-identical to
an uninterrupted one."""

import json

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from dsnet_core.errors import ConfigError
from dsnet_core.io.semantickitti import SemanticKittiReader
from dsnet_core.model.checkpoint import load_checkpoint
from dsnet_core.synth.stream import StreamOptions
from dsnet_core.train.loop import TrainConfig, Trainer
from dsnet_core.train.stream import StreamLog
from tests.dsnet_core.train.test_loop import LM, TINY
from tests.helpers.tiny_log import write_tiny_log

FAST = StreamOptions(frames=1, styles=("classic",), sensors=("vlp16",))


@pytest.fixture(autouse=True, scope="module")
def one_thread():
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture(scope="module")
def val(tmp_path_factory):
    return write_tiny_log(tmp_path_factory.mktemp("val"), frames=2)


def test_windows_are_disjoint_and_volumes_take_k_frames():
    log = StreamLog(0, StreamOptions(frames=2, styles=("classic",), sensors=("vlp16",)), steps=3)
    a, b, c = log.window(0, 0), log.window(0, 1), log.window(1, 0)
    assert len(a) == 3 and not (set(a) & set(b)) and not (set(a) & set(c)) and not (set(b) & set(c))
    assert log.window(0, 1) == b  # a function of (stage, epoch) only
    vol = log.volumes(a[:1])[0]
    assert [r.index for r in vol] == [0, 1] and vol[-1].sequence == a[0]
    scan, label = log.scan(vol[1]), log.labels(vol[1])
    assert scan.dtype == np.float32 and scan.shape[1] == 4 and label.shape == (scan.shape[0],)
    assert np.allclose(log.pose(vol[0]), np.eye(4))  # poses relative to the sample's first frame
    with pytest.raises(ConfigError):
        StreamLog(0, StreamOptions(styles=("no-such-style",)), steps=1)


def test_prefetching_workers_return_the_serial_samples():
    names = StreamLog(3, FAST, steps=2).window(0, 0)
    serial, ahead = StreamLog(3, FAST, steps=2), StreamLog(3, FAST, steps=2, workers=1)
    try:
        ahead.window(0, 0)
        ahead.prefetch(names)
        for n in names:
            ref = serial.frames(n)[0]
            assert np.array_equal(serial.scan(ref), ahead.scan(ref))
            assert np.array_equal(serial.labels(ref), ahead.labels(ref))
    finally:
        ahead.close()


def _trainer(val, out, resume=False, epochs=2):
    reader = StreamLog(0, FAST, steps=2)
    cfg = TrainConfig(stage="semantic", epochs={"semantic": epochs}, lr=0.01, augment=False)
    vreader = SemanticKittiReader(val)
    return Trainer(out, TINY, reader, reader.probe(2), vreader, ["00"], LM, cfg, resume=resume)


def test_stream_training_resumes_bit_identically_and_sees_new_samples(val, tmp_path):
    t = _trainer(val, tmp_path / "a")
    straight = t.run()
    assert straight.training_data["stream"]["samples_per_epoch"] == 2
    seen = set(t.reader.sequences())  # the last epoch's window
    assert seen and not seen & set(t.reader.window(0, 0))
    _trainer(val, tmp_path / "b", epochs=1).run()
    resumed = _trainer(val, tmp_path / "b", resume=True).run()
    assert [m["train_loss"] for m in resumed.metrics] == [m["train_loss"] for m in straight.metrics]
    a, _ = load_checkpoint(tmp_path / "a")
    b, _ = load_checkpoint(tmp_path / "b")
    for (k, x), (_, y) in zip(a.state_dict().items(), b.state_dict().items(), strict=True):
        assert torch.equal(x, y), k


def test_cli_stream_needs_validation_data_and_records_the_stream(val, tmp_path):
    from flows.cli import app

    runner = CliRunner()
    res = runner.invoke(app, ["train", "dsnet", "--out", str(tmp_path / "x"), "--stream", "2"])
    assert res.exit_code == 2 and "--stream needs --val-data" in res.output
    res = runner.invoke(
        app,
        ["train", "dsnet", str(val), "--out", str(tmp_path / "x"), "--stream", "2", "--val-data", str(val)],
    )
    assert res.exit_code == 2 and "not both or neither" in res.output
    args = [
        "train",
        "dsnet",
        "--out",
        str(tmp_path / "s"),
        "--stream",
        "2",
        "--val-data",
        str(val),
        "--grid",
        "24,32,8",
    ]
    args += [
        "--stream-styles",
        "classic",
        "--stream-sensors",
        "vlp16",
        "--stream-workers",
        "0",
        "--no-augment",
    ]
    res = runner.invoke(app, [*args, "--stage", "semantic", "--epochs", "semantic=1"])
    assert res.exit_code == 0, res.output
    card = json.loads((tmp_path / "s" / "card.json").read_text())
    assert card["training_data"]["stream"] == {
        "seed": 0, "samples_per_epoch": 2, "frames": 1, "styles": ["classic"], "sensors": ["vlp16"],
    }  # fmt: skip
    assert card["epochs"] == {"semantic": 1}
