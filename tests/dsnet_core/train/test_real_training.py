"""``dsnet train dsnet … --real DIR``: real labelled scans mixed into training.

A tiny real-like log (``dsnet synth``'s generator, some points relabelled to raw 99 "other-object"
and raw 0 "unlabelled" and some thing points' instance ids cleared, as PandaSet's uncuboided thing
points) stands in for PandaSet."""

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from dsnet_core.adapt.mixing import laser_masks
from dsnet_core.errors import ConfigError
from dsnet_core.io.semantickitti import SemanticKittiReader
from dsnet_core.model.checkpoint import load_checkpoint
from dsnet_core.model.losses import voxel_labels
from dsnet_core.model.network import NetOutput
from dsnet_core.synth import generate_log
from dsnet_core.synth.stream import StreamOptions
from dsnet_core.train.data import load_sample
from dsnet_core.train.loop import TrainConfig, Trainer
from dsnet_core.train.real import RealData, RealOptions, centres_of, mix_samples
from dsnet_core.train.stream import StreamLog
from tests.dsnet_core.train.test_loop import LM, TINY
from tests.helpers.tiny_log import write_tiny_log

FAST = StreamOptions(frames=1, styles=("classic",), sensors=("vlp16",))
ATTRIBUTION = "PandaSet by Hesai and Scale AI, CC BY 4.0"


@pytest.fixture(autouse=True, scope="module")
def one_thread():
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture(scope="module")
def real(tmp_path_factory) -> Path:
    """Sequences 30 (3 frames, trained on) and 31 (1 frame) of a real-like log: every 7th point
    raw 99, every 11th raw 0, every 5th thing point without instance id."""
    root = tmp_path_factory.mktemp("real")
    generate_log(root, sequences=2, frames=3, seed=5, sensor="vlp16", first_sequence=30)
    is_thing = LM.is_thing()
    for path in sorted(root.glob("sequences/*/labels/*.label")):
        label = np.fromfile(path, np.uint32)
        sem = label & 0xFFFF
        ids = label >> 16
        i = np.arange(len(label))
        thing = is_thing[LM.to_train(sem)] & (ids > 0)
        ids = np.where(thing & (i % 5 == 0), 0, ids)
        sem = np.where(i % 7 == 0, 99, np.where(i % 11 == 0, 0, sem))
        (sem | (ids << 16)).astype(np.uint32).tofile(path)
    return root


@pytest.fixture(scope="module")
def val(tmp_path_factory):
    return write_tiny_log(tmp_path_factory.mktemp("val"), frames=1)


def _real(root, share=1.0, mix="both", seqs=("30",), scans=1):
    opts = RealOptions(Path(root), tuple(seqs), share, mix, ATTRIBUTION)
    return RealData(SemanticKittiReader(root), opts, scans, LM)


def _trainer(val, out, real, resume=False, epochs=2, stage="semantic"):
    reader = StreamLog(0, FAST, steps=2)
    cfg = TrainConfig(stage=stage, epochs={stage: epochs}, lr=0.01)
    vreader = SemanticKittiReader(val)
    return Trainer(out, TINY, reader, reader.probe(2), vreader, ["00"], LM, cfg, resume=resume, real=real)


def test_label_map_sends_other_object_and_unlabelled_to_ignore(real):
    assert LM.to_train(np.array([99, 0], np.uint32)).tolist() == [0, 0]
    data = _real(real)
    s = data.load(0, None)
    raw = SemanticKittiReader(real).labels(data.volumes[0][0]) & 0xFFFF
    assert np.all(s.sem[(raw == 99) | (raw == 0)] == 0)
    assert not s.thing[s.sem == 0].any()  # masked points give no offset target either
    label = SemanticKittiReader(real).labels(data.volumes[0][0])
    thing_class = LM.is_thing()[LM.to_train(label & 0xFFFF)]
    no_id = thing_class & ((label >> 16) == 0)
    assert no_id.any() and not s.thing[no_id].any()  # thing points in no cuboid: no offset loss


def test_masked_points_contribute_no_loss(real, val, tmp_path):
    """Changing the predictions of raw-99 / raw-0 points (voxels holding only such points, and
    their offsets) leaves the semantic and offset losses unchanged; changing a labelled voxel's
    does not."""
    t = _trainer(val, tmp_path / "m", _real(real, share=1.0, mix="none"))
    s = t.real.load(0, None)
    pts = torch.from_numpy(s.points)
    with torch.no_grad():
        out = t.model([pts], instance=True)
    vsem = voxel_labels(out.point_to_voxel, torch.from_numpy(s.sem), out.voxel_logits.shape[0], 20)
    masked_vox = vsem == 0
    assert masked_vox.any() and (~masked_vox).any()
    gen = torch.Generator().manual_seed(0)

    def losses(o: NetOutput) -> tuple[float, float]:
        return float(t._semantic_loss(o, [s])), float(t._offset_loss(o, [pts], [s]))

    base = losses(out)
    logits = out.voxel_logits.clone()
    logits[masked_vox] = torch.randn(int(masked_vox.sum()), 20, generator=gen) * 10
    offsets = out.offsets.clone()
    no_target = ~torch.from_numpy(s.thing)
    offsets[no_target] = torch.randn(int(no_target.sum()), 3, generator=gen) * 10
    changed = replace(out, voxel_logits=logits, offsets=offsets)
    assert losses(changed) == pytest.approx(base, rel=1e-6, abs=1e-7)
    logits2 = out.voxel_logits.clone()
    logits2[~masked_vox] += torch.randn(int((~masked_vox).sum()), 20, generator=gen) * 10
    moved = replace(out, voxel_logits=logits2)
    assert abs(losses(moved)[0] - base[0]) > 1e-3


@pytest.mark.parametrize("mode", ["laser", "polar", "none"])
def test_mixing_keeps_points_and_labels_paired(real, mode):
    data = _real(real)
    a, b = data.load(0, None), data.load(1, None)
    b = type(b)(b.points, b.sem, b.inst & ~(1 << 38), b.thing, b.frame_index, b.name)  # a "synthetic" scan
    rng = np.random.default_rng(3)
    m = mix_samples(a, b, mode, rng)
    n = len(m.sem)
    for arr in (m.points, m.inst, m.thing, m.frame_index, m.centre):
        assert len(arr) == n
    # every mixed point is a point of a or of b with its own label, instance and centre
    ca, cb = centres_of(a), centres_of(b)
    rows = {
        tuple(p): (int(s), int(i), tuple(c)) for p, s, i, c in zip(a.points, a.sem, a.inst, ca, strict=True)
    }
    rows_b = {
        tuple(p): (int(s), int(i), tuple(c)) for p, s, i, c in zip(b.points, b.sem, b.inst, cb, strict=True)
    }
    from_a = 0
    for p, s, i, c in zip(m.points, m.sem, m.inst, m.centre, strict=True):
        key = tuple(p)
        got = (int(s), int(i), tuple(c))
        if key in rows and rows[key] == got:
            from_a += 1
        else:
            assert rows_b[key] == got
    if mode == "none":
        assert n == len(a.sem) and from_a == n
    else:
        assert 0 < from_a < n  # both scans contribute
        assert (m.inst[:from_a] & (1 << 38) > 0).sum() == (m.inst[:from_a] > 0).sum()  # real keys marked
    # the two complementary mixes of laser mode hold every point exactly once
    if mode == "laser":
        ea, eb = laser_masks(a.points, b.points, 4)
        assert ea.sum() + (~ea).sum() + eb.sum() + (~eb).sum() == len(a.sem) + len(b.sem)


def test_mixed_centres_are_whole_scan_centres(real):
    data = _real(real)
    a = data.load(0, None)
    m = mix_samples(a, a, "laser", np.random.default_rng(0))
    whole = centres_of(a)
    for key in np.unique(a.inst[a.thing])[:5]:
        assert np.allclose(m.centre[m.inst == key], whole[a.inst == key][0])


def test_card_records_real_data_and_attribution(real, val, tmp_path):
    t = _trainer(val, tmp_path / "c", _real(real, share=0.5), epochs=1)
    card = t.run()
    rec = card.training_data["real"]
    assert rec["root"] == str(Path(real).resolve()) and rec["sequences"] == ["30"]
    assert rec["frames"] == 3 and rec["files"] == 6 and rec["attribution"] == ATTRIBUTION
    assert rec["frame_names"] == ["30/000000", "30/000001", "30/000002"]
    assert len(rec["sha256"]) == 64 and rec["share"] == 0.5 and rec["mix"] == "both"
    assert sum(rec["class_points"]) > 0
    # the sha256 covers the content: one changed byte changes it
    again = _real(real, share=0.5).record()
    assert again["sha256"] == rec["sha256"]


def test_resume_refuses_a_changed_real_and_matches_an_uninterrupted_run(real, val, tmp_path):
    straight = _trainer(val, tmp_path / "a", _real(real, share=0.5), epochs=2).run()
    _trainer(val, tmp_path / "b", _real(real, share=0.5), epochs=1).run()
    for other, words in [
        (_real(real, share=0.25), "share"),
        (_real(real, share=0.5, seqs=("30", "31")), "sequences"),
        (None, "trained with --real"),
    ]:
        with pytest.raises(ConfigError, match=words):
            _trainer(val, tmp_path / "b", other, resume=True)
    resumed = _trainer(val, tmp_path / "b", _real(real, share=0.5), resume=True).run()
    assert [m["train_loss"] for m in resumed.metrics] == [m["train_loss"] for m in straight.metrics]
    a, _ = load_checkpoint(tmp_path / "a")
    b, _ = load_checkpoint(tmp_path / "b")
    for (k, x), (_, y) in zip(a.state_dict().items(), b.state_dict().items(), strict=True):
        assert torch.equal(x, y), k


def test_real_options_refuse_bad_input(real):
    with pytest.raises(ConfigError, match="no sequence 33"):
        _real(real, seqs=("33",))
    with pytest.raises(ConfigError, match="--real-share"):
        RealOptions(Path(real), ("30",), share=0.0)
    with pytest.raises(ConfigError, match="--real-sequences"):
        RealOptions(Path(real), ())


def test_real_volumes_of_two_scans_use_the_poses(real):
    data = _real(real, scans=2)
    s = data.load(1, None)
    assert set(np.unique(s.frame_index).tolist()) == {0, 1}
    single = load_sample(SemanticKittiReader(real), data.volumes[1][-1:], LM)
    assert len(s.sem) > len(single.sem)


def test_cli_real_needs_named_sequences_and_records_them(real, val, tmp_path):
    from flows.cli import app

    runner = CliRunner()
    base = ["train", "dsnet", "--stream", "2", "--val-data", str(val), "--grid", "24,32,8"]
    base += ["--stream-styles", "classic", "--stream-sensors", "vlp16", "--stream-workers", "0"]
    base += ["--stage", "semantic", "--epochs", "semantic=1"]
    res = runner.invoke(app, [*base, "--out", str(tmp_path / "x"), "--real", str(real)])
    assert res.exit_code == 2 and "--real-sequences" in res.output
    clash = ["--real", str(real), "--real-sequences", "30", "--val-data", str(real), "--val-sequences", "30"]
    res = runner.invoke(app, [*base, "--out", str(tmp_path / "y"), *clash])
    assert res.exit_code == 2 and "also validation sequences" in res.output
    args = [*base, "--out", str(tmp_path / "s"), "--real", str(real), "--real-sequences", "30"]
    res = runner.invoke(app, [*args, "--real-attribution", ATTRIBUTION, "--real-mix", "laser"])
    assert res.exit_code == 0, res.output
    card = json.loads((tmp_path / "s" / "card.json").read_text())
    assert card["training_data"]["real"]["attribution"] == ATTRIBUTION
    assert card["training_data"]["real"]["mix"] == "laser"


def test_every_bundled_model_that_saw_real_data_carries_its_attribution():
    """A bundled card with a ``training_data.real`` record names its attribution, and the models
    README carries that text (none is bundled today: the rule guards the next one)."""
    import dsnet_core

    models = Path(dsnet_core.__file__).parent / "data" / "models"
    readme = (models / "README.md").read_text()
    for card_path in sorted(models.glob("*/card.json")):
        real_record = json.loads(card_path.read_text())["training_data"].get("real")
        if real_record is None:
            continue
        assert real_record.get("attribution"), f"{card_path}: saw {real_record['root']} without attribution"
        assert real_record["attribution"] in readme, (
            f"{card_path}: its attribution is not in {models}/README.md"
        )
