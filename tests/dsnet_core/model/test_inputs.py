"""The network's input options (remission raw / none / rank, remission dropout, height above the
fitted ground): the spec, rank normalisation's invariance, the ground fit's golden heights, the
same features in training and at inference, the card, and the default path unchanged."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from dsnet_core.errors import ConfigError
from dsnet_core.io.semantickitti import SemanticKittiReader
from dsnet_core.labels import class_map_of, load_label_map
from dsnet_core.model.checkpoint import ModelCard, read_card, save_checkpoint
from dsnet_core.model.ground_height import height_above_ground
from dsnet_core.model.inference import Predictor
from dsnet_core.model.inputs import (
    InputSpec,
    MissingInputError,
    build_inputs,
    check_log_inputs,
    rank_normalise,
)
from dsnet_core.model.network import DSNet
from dsnet_core.model.presets import ModelConfig
from dsnet_core.train.data import load_sample, volume_refs
from tests.model_helpers import TEST_CONFIG

LM = load_label_map("semantic-kitti")


def _config(inputs: str, dropout: float = 0.0) -> ModelConfig:
    return replace(TEST_CONFIG, inputs=inputs, remission_dropout=dropout)


# -- the spec ----------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("text", "remission", "height", "canonical"),
    [
        ("xyz,remission", "raw", False, "xyz,remission"),
        ("xyz", "none", False, "xyz"),
        ("remission-rank,xyz", "rank", False, "xyz,remission-rank"),
        ("height, xyz", "none", True, "xyz,height"),
        ("xyz,height,remission-rank", "rank", True, "xyz,remission-rank,height"),
    ],
)
def test_spec_parses_to_a_canonical_form(text, remission, height, canonical):
    spec = InputSpec.parse(text)
    assert (spec.remission, spec.height, str(spec)) == (remission, height, canonical)
    assert replace(TEST_CONFIG, inputs=text).inputs == canonical


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("xyz,intensity", "unknown input 'intensity'"),
        ("remission", "xyz is required"),
        ("xyz,remission,remission-rank", "choose one of remission, remission-rank"),
        ("xyz,xyz", "named twice"),
    ],
)
def test_bad_spec_is_one_line_naming_the_problem(text, message):
    with pytest.raises(ConfigError, match=message):
        InputSpec.parse(text)


def test_remission_dropout_range():
    with pytest.raises(ConfigError, match=r"remission dropout must be in \[0, 1\), got 1.0"):
        replace(TEST_CONFIG, remission_dropout=1.0)


# -- rank normalisation ------------------------------------------------------------------------
def test_rank_values_with_ties_and_constants():
    r = rank_normalise(torch.tensor([0.3, 0.1, 0.3, 0.9, 0.0]))
    # sorted: 0.0 (rank 0), 0.1 (1), 0.3 0.3 (2, 3 → 2.5), 0.9 (4); divided by N - 1 = 4
    assert torch.equal(r, torch.tensor([0.625, 0.25, 0.625, 1.0, 0.0]))
    assert torch.equal(rank_normalise(torch.full((7,), 0.42)), torch.full((7,), 0.5))
    assert torch.equal(rank_normalise(torch.tensor([0.8])), torch.tensor([0.5]))


def test_rank_is_invariant_to_a_monotonic_remission_transform():
    rng = np.random.default_rng(3)
    rem = rng.integers(0, 256, 20000).astype(np.float64) / 255.0  # 8-bit remission: many ties
    transformed = 0.1 + 0.7 * rem**2 + 0.05 * np.sqrt(rem)  # strictly increasing on [0, 1]
    assert np.unique(transformed.astype(np.float32)).size == np.unique(rem).size  # no new ties
    a = rank_normalise(torch.from_numpy(rem.astype(np.float32)))
    b = rank_normalise(torch.from_numpy(transformed.astype(np.float32)))
    assert torch.equal(a, b)
    assert float(a.min()) >= 0.0 and float(a.max()) <= 1.0


# -- height above the fitted ground ------------------------------------------------------------
def _scene() -> tuple[np.ndarray, np.ndarray]:
    """Flat ground at z = -1.7 (points out to 40 m) with a 4 × 2 × 1.5 m box standing on it at
    (10, 5): its top and four sides sampled, nothing under it. Returns xyz and the true heights."""
    rng = np.random.default_rng(0)
    g = rng.uniform(-40, 40, (40000, 2))
    box_lo, box_hi = np.array([8.0, 4.0, -1.7]), np.array([12.0, 6.0, -0.2])
    g = g[~((g[:, 0] > 8) & (g[:, 0] < 12) & (g[:, 1] > 4) & (g[:, 1] < 6))]
    ground = np.column_stack([g, np.full(len(g), -1.7)])
    faces = []
    for axis in range(3):
        for side in (box_lo, box_hi):
            if axis == 2 and side is box_lo:
                continue  # the box stands on the ground: no bottom face
            f = rng.uniform(box_lo, box_hi, (800, 3))
            f[:, axis] = side[axis]
            faces.append(f)
    box = np.concatenate(faces)
    xyz = np.concatenate([ground, box])
    return xyz, xyz[:, 2] + 1.7


def test_height_golden_values_on_a_flat_ground_with_a_box():
    xyz, truth = _scene()
    h = height_above_ground(xyz)
    assert np.abs(h - truth).max() < 0.01
    top = np.isclose(xyz[:, 2], -0.2)
    assert np.allclose(h[top], 1.5, atol=0.01)


def test_height_follows_a_slope_and_ignores_point_order():
    xyz, _ = _scene()
    tilted = xyz.copy()
    tilted[:, 2] += 0.02 * xyz[:, 0]  # a 2 % slope: ground height 0 along it
    h = height_above_ground(tilted)
    on_ground = np.isclose(xyz[:, 2], -1.7)
    inner = on_ground & (np.abs(xyz[:, :2]).max(1) < 36)  # the last cells of the returns extrapolate
    # a cell's low order statistic sits below its centre on a slope: +0.45·2 %·2 m ≈ 1.8 cm
    assert np.median(np.abs(h[inner] - 0.018)) < 0.003
    assert np.abs(h[inner]).max() < 0.06 and np.abs(h[on_ground]).max() < 0.1
    perm = np.random.default_rng(1).permutation(len(xyz))
    assert np.array_equal(height_above_ground(tilted[perm]), h[perm])


def test_height_of_an_empty_cloud():
    assert height_above_ground(np.zeros((0, 3))).shape == (0,)


# -- building the inputs -----------------------------------------------------------------------
def _cloud(n: int = 500, seed: int = 0) -> torch.Tensor:
    rng = np.random.default_rng(seed)
    pts = np.column_stack([rng.uniform(-20, 20, (n, 2)), rng.uniform(-1.8, 1.0, n), rng.uniform(0, 1, n)])
    return torch.from_numpy(pts.astype(np.float32))


def test_build_inputs_per_option():
    c = _cloud()
    (raw,) = build_inputs([c], InputSpec.parse("xyz,remission"))
    assert raw is c  # the default passes the reader's cloud through
    (none,) = build_inputs([c], InputSpec.parse("xyz"))
    assert torch.equal(none[:, :3], c[:, :3]) and not none[:, 3].any()
    (rank,) = build_inputs([c], InputSpec.parse("xyz,remission-rank,height"))
    assert rank.shape == (500, 5)
    assert torch.equal(rank[:, 3], rank_normalise(c[:, 3]))
    expect_h = torch.from_numpy(height_above_ground(c[:, :3].numpy()).astype(np.float32))
    assert torch.equal(rank[:, 4], expect_h)
    assert torch.equal(c, _cloud())  # the input is not modified


def test_remission_dropout_only_in_training():
    c = _cloud()
    spec = InputSpec.parse("xyz,remission-rank")
    torch.manual_seed(0)
    dropped = [build_inputs([c], spec, dropout=0.5, training=True)[0] for _ in range(40)]
    constant = [bool((d[:, 3] == 0.5).all()) for d in dropped]
    assert 5 < sum(constant) < 35  # about half the draws replace it by the constant's rank, 0.5
    assert all(
        torch.equal(d[:, 3], rank_normalise(c[:, 3])) for d, k in zip(dropped, constant, strict=True) if not k
    )
    (evaluated,) = build_inputs([c], spec, dropout=0.99, training=False)
    assert torch.equal(evaluated[:, 3], rank_normalise(c[:, 3]))


def test_network_reads_its_inputs_and_none_ignores_remission():
    torch.manual_seed(0)
    m = DSNet(_config("xyz,height")).eval()
    assert m.point_encoder.mlp[0].num_features == 10  # the 9 features + height
    c = _cloud()
    other = c.clone()
    other[:, 3] = torch.rand(len(c))
    with torch.no_grad():
        a, b = m([c]).logits, m([other]).logits
    assert torch.equal(a, b)  # xyz only: remission changes nothing


def test_equivariant_network_with_height():
    cfg = replace(_config("xyz,remission-rank,height"), equivariant=4)
    torch.manual_seed(0)
    m = DSNet(cfg).eval()
    with torch.no_grad():
        out = m([_cloud()])
    assert out.logits.shape == (500, cfg.num_classes)


# -- training features == inference features ---------------------------------------------------
def test_training_and_inference_build_the_same_features(synth_log, tmp_path):
    """The trainer's sample (load_sample) and the predictor's cloud of the same scan reach the
    point MLP as the same (N, 10) features, and give the same logits."""
    torch.manual_seed(0)
    model = DSNet(_config("xyz,remission-rank,height", dropout=0.3))
    card = ModelCard(architecture={}, class_map=class_map_of(LM), training_data={}, code_version="test")
    save_checkpoint(tmp_path / "ck", model, card)
    reader = SemanticKittiReader(synth_log)
    refs = volume_refs(reader, ["00"], 1)[2]
    seen: list[torch.Tensor] = []

    def grab(_module, args):
        seen.append(args[0].detach().clone())

    model.eval()
    handle = model.point_encoder.register_forward_pre_hook(grab)
    with torch.no_grad():
        train_logits = model([torch.from_numpy(load_sample(reader, refs, LM).points)]).logits
    handle.remove()
    predictor = Predictor.from_checkpoint(tmp_path / "ck")
    predictor.model.point_encoder.register_forward_pre_hook(grab)
    result = predictor.predict(reader.scan(refs[-1]))
    assert seen[0].shape[1] == 10
    assert torch.equal(seen[0], seen[1])
    expect = (train_logits[:, 1:].argmax(1) + 1).numpy()
    assert np.array_equal(result.sem, expect)


# -- the card and the refusal ------------------------------------------------------------------
def test_card_records_the_inputs_and_the_default_card_is_unchanged(tmp_path):
    card = ModelCard(architecture={}, class_map=class_map_of(LM), training_data={}, code_version="test")
    save_checkpoint(tmp_path / "a", DSNet(_config("height,xyz,remission-rank", 0.3)), card)
    arch = read_card(tmp_path / "a").architecture
    assert (arch["inputs"], arch["remission_dropout"]) == ("xyz,remission-rank,height", 0.3)
    assert read_card(tmp_path / "a").config.input_spec == InputSpec("rank", True)
    default = TEST_CONFIG.to_dict()
    assert "inputs" not in default and "remission_dropout" not in default  # old cards compare equal
    assert ModelConfig.from_dict(default).inputs == "xyz,remission"


def test_refusal_names_the_log_the_sequence_and_the_input():
    spec = InputSpec.parse("xyz,remission-rank")
    with pytest.raises(MissingInputError) as err:
        check_log_inputs(spec, "/logs/bare", "03", "none", "ck-rank")
    msg = str(err.value)
    assert "\n" not in msg
    assert msg == (
        "/logs/bare: sequence 03 has no intensity channel, but model ck-rank needs input "
        "'remission-rank' (its inputs: xyz,remission-rank); label with a model trained with --inputs xyz"
    )
    check_log_inputs(spec, "/logs/bare", "03", "uint8", "ck-rank")  # an intensity channel: fine
    check_log_inputs(InputSpec.parse("xyz,height"), "/logs/bare", "03", "none", "ck")  # needs none


def _bare_pcd_log(root) -> None:
    """A folder log (sequence ``drive1``) of two ASCII PCD scans with x y z and no intensity."""
    from tests.helpers.tiny_log import tiny_frame

    seq = root / "drive1"
    seq.mkdir(parents=True)
    for i in range(2):
        pts = tiny_frame(i, n=1200)[0][:, :3]
        head = (
            "VERSION .7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n"
            f"WIDTH {len(pts)}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {len(pts)}\nDATA ascii\n"
        )
        (seq / f"{i:06d}.pcd").write_text(
            head + "\n".join(" ".join(f"{v:.4f}" for v in p) for p in pts) + "\n"
        )


def test_infer_stage_refuses_a_log_without_intensity_for_a_remission_model(tmp_path):
    from storage.run import RunStore
    from tasks.methods import get_pipeline
    from tests.helpers.plain_runner import prepare_stage, run_stage_plain

    _bare_pcd_log(tmp_path / "log")
    card = ModelCard(architecture={}, class_map=class_map_of(LM), training_data={}, code_version="test")
    pipeline = get_pipeline(refine=False)
    store = RunStore(tmp_path / "run")

    def run_for(ckpt):
        return {
            **pipeline.record(),
            "data": str(tmp_path / "log"),
            "stages": {"align": {"scans": 1}, "infer": {"checkpoint": str(ckpt)}},
            "options": {"block_size": 2},
        }

    rank = save_checkpoint(tmp_path / "rank", DSNet(_config("xyz,remission-rank")), card)
    run = run_for(rank)
    store.write_run_config("r1", run)
    for stage in ("ingest", "align"):
        run_stage_plain(store, pipeline, "drive1", stage, run, "r1")
    with pytest.raises(MissingInputError) as err:
        prepare_stage(store, pipeline, "drive1", "infer", run, "r1")
    assert str(err.value).startswith(f"{tmp_path / 'log'}: sequence drive1 has no intensity channel")
    assert "needs input 'remission-rank'" in str(err.value) and "\n" not in str(err.value)
    xyz = save_checkpoint(tmp_path / "xyz", DSNet(_config("xyz,height")), card)  # needs no remission
    ok = run_for(xyz)
    store.write_run_config("r2", ok)
    assert run_stage_plain(store, pipeline, "drive1", "infer", ok, "r2").n_items == 2


def test_train_options_set_the_inputs_and_a_fine_tune_keeps_its_parents(tmp_path):
    from tasks.methods.dsnet_train import DsnetTrainOptions, _check_inherited_inputs, model_config

    opts = DsnetTrainOptions(out=tmp_path / "o", inputs="xyz,height,remission-rank", remission_dropout=0.3)
    cfg = model_config(opts)
    assert (cfg.inputs, cfg.remission_dropout) == ("xyz,remission-rank,height", 0.3)
    assert model_config(DsnetTrainOptions(out=tmp_path / "o")) == model_config(
        DsnetTrainOptions(out=tmp_path / "o", inputs="xyz,remission")
    )
    with pytest.raises(ConfigError, match="unknown input 'hieght'"):
        model_config(DsnetTrainOptions(out=tmp_path / "o", inputs="xyz,hieght"))
    card = ModelCard(architecture={}, class_map=class_map_of(LM), training_data={}, code_version="test")
    parent = save_checkpoint(tmp_path / "p", DSNet(_config("xyz,remission-rank")), card)
    _check_inherited_inputs(DsnetTrainOptions(out=tmp_path / "o"), parent)  # not given: inherited
    _check_inherited_inputs(DsnetTrainOptions(out=tmp_path / "o", inputs="remission-rank,xyz"), parent)
    with pytest.raises(ConfigError, match="trained with inputs xyz,remission-rank; a fine-tune keeps"):
        _check_inherited_inputs(DsnetTrainOptions(out=tmp_path / "o", inputs="xyz"), parent)


def test_a_checkpoint_refuses_to_load_as_other_inputs(tmp_path):
    from dsnet_core.errors import CheckpointMismatchError
    from dsnet_core.model.checkpoint import load_checkpoint

    card = ModelCard(architecture={}, class_map=class_map_of(LM), training_data={}, code_version="test")
    save_checkpoint(tmp_path / "r", DSNet(_config("xyz,remission-rank")), card)
    load_checkpoint(tmp_path / "r", expect_config=_config("remission-rank,xyz"))
    with pytest.raises(
        CheckpointMismatchError, match="inputs: expected None, checkpoint has 'xyz,remission-rank'"
    ):
        load_checkpoint(tmp_path / "r", expect_config=TEST_CONFIG)  # e.g. --resume without --inputs
