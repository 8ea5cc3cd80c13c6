"""Matching a log's clouds to the training sensor (``infer.match``): the ground under the origin,
the remission quantiles by rank, the card's reference, the refusal of a card without one, and the
default path unchanged."""

from __future__ import annotations

import numpy as np
import pytest

from dsnet_core.errors import ConfigError
from dsnet_core.labels import class_map_of, load_label_map
from dsnet_core.model.checkpoint import ModelCard, save_checkpoint
from dsnet_core.model.inference import Predictor
from dsnet_core.model.network import DSNet
from dsnet_core.model.sensor_match import (
    LEVELS,
    SensorMatch,
    SensorReference,
    ground_below,
    mid_rank,
    reference_of,
)
from tests.model_helpers import TEST_CONFIG

LM = load_label_map("semantic-kitti")


def _street(ground: float, seed: int = 0, n: int = 30000) -> np.ndarray:
    """float32 (N, 4): a flat ground at ``ground`` out to 40 m, a 4 × 2 × 1.5 m box at (9, 3),
    points on the ego vehicle's roof (within 2 m, 0.3–1.5 m above the origin, as PandaSet has),
    and remission in [0, 0.1] as 8-bit codes (a dark sensor: code / 255, codes 0–25)."""
    rng = np.random.default_rng(seed)
    g = rng.uniform(-40, 40, (n, 2))
    pts = [np.column_stack([g, np.full(n, ground)])]
    box = rng.uniform([7, 2, ground], [11, 4, ground + 1.5], (2000, 3))
    ego = rng.uniform([-1.5, -1, 0.3], [1.5, 1, 1.5], (1500, 3))
    xyz = np.concatenate([*pts, box, ego])
    rem = rng.integers(0, 26, len(xyz)) / 255.0
    return np.column_stack([xyz, rem]).astype(np.float32)


def _reference(ground: float = -1.73) -> SensorReference:
    return SensorReference(ground, tuple(float(v) for v in np.linspace(0.05, 0.85, LEVELS)))


def test_ground_below_sees_past_the_ego_vehicle():
    for ground in (-1.73, -0.3, 0.4):
        got = ground_below(_street(ground)[:, :3])
        assert got == pytest.approx(ground, abs=0.01)
    assert ground_below(np.zeros((0, 3))) is None
    far = np.column_stack([np.full(10, 60.0), np.zeros(10), np.zeros(10)])
    assert ground_below(far) is None  # no return within the ring


def test_ground_match_moves_the_cloud_to_the_reference_height_whatever_its_origin():
    ref = _reference(-1.73)
    match = SensorMatch(ref, "ground")
    low = _street(-0.3)
    out = match(low)
    assert out.dtype == np.float32 and out.shape == low.shape
    assert ground_below(out[:, :3]) == pytest.approx(-1.73, abs=0.01)
    np.testing.assert_array_equal(out[:, [0, 1, 3]], low[:, [0, 1, 3]])  # x, y, remission untouched
    shift = out[:, 2] - low[:, 2]
    assert np.ptp(shift) < 1e-5 and shift[0] == pytest.approx(-1.43, abs=0.01)  # one translation
    # the same street 0.7 m higher (the ego returns stay where they are) reaches the same input
    street = slice(0, len(low) - 1500)
    np.testing.assert_allclose(match(_street(0.4))[street, 2], out[street, 2], atol=1e-4)


def test_remission_match_depends_only_on_the_order_of_the_values():
    ref = _reference()
    match = SensorMatch(ref, "remission")
    cloud = _street(-1.73)
    out = match(cloud)
    brighter = cloud.copy()
    codes = np.rint(cloud[:, 3] * 255).astype(int)
    brighter[:, 3] = (np.sqrt(np.arange(256) / 255) * 0.9 + 0.05)[codes]  # an increasing recalibration
    np.testing.assert_array_equal(match(brighter)[:, 3], out[:, 3])
    np.testing.assert_array_equal(out[:, :3], cloud[:, :3])
    assert 0.05 <= out[:, 3].min() < 0.1 and 0.8 < out[:, 3].max() <= 0.85  # ties: mid-ranks
    assert np.median(out[:, 3]) == pytest.approx(0.45, abs=0.02)  # the reference's median (26 codes)
    assert np.array_equal(np.argsort(out[:, 3], kind="stable"), np.argsort(cloud[:, 3], kind="stable"))


def test_mid_rank_values_with_ties():
    np.testing.assert_array_equal(
        mid_rank(np.array([3.0, 1.0, 1.0, 2.0, 5.0])), [0.75, 0.125, 0.125, 0.5, 1.0]
    )
    np.testing.assert_array_equal(mid_rank(np.array([7.0])), [0.5])
    np.testing.assert_array_equal(mid_rank(np.full(4, 0.2)), [0.5] * 4)


def test_both_is_ground_then_remission_and_empty_clouds_pass():
    ref = _reference()
    cloud = _street(-0.3)
    both = SensorMatch(ref, "both")(cloud)
    np.testing.assert_array_equal(both[:, :3], SensorMatch(ref, "ground")(cloud)[:, :3])
    np.testing.assert_array_equal(both[:, 3], SensorMatch(ref, "remission")(cloud)[:, 3])
    assert SensorMatch(ref, "both")(np.zeros((0, 4), np.float32)).shape == (0, 4)
    with pytest.raises(ConfigError, match="match must be one of auto, none, ground, remission, both"):
        SensorMatch(ref, "sideways")


def test_reference_of_training_clouds_is_rounded_and_round_trips():
    clouds = [_street(-1.8, seed=s) for s in range(3)]
    ref = reference_of(clouds)
    assert ref.ground == pytest.approx(-1.8, abs=0.01) and ref.ground == round(ref.ground, 3)
    q = np.asarray(ref.remission)
    assert len(q) == LEVELS and np.all(np.diff(q) >= 0) and np.array_equal(q, np.round(q, 4))
    assert q[0] == 0.0 and q[-1] == round(25 / 255, 4)
    assert SensorReference.from_dict(ref.to_dict(), "card.json") == ref
    with pytest.raises(ValueError, match="no training cloud has ground returns"):
        reference_of([np.zeros((0, 4), np.float32)])


@pytest.mark.parametrize(
    ("data", "message"),
    [
        ({"ground": -1.7}, "sensor_reference is malformed"),
        ({"ground": "low", "remission_quantiles": [0.1] * LEVELS}, "sensor_reference is malformed"),
        ({"ground": 40.0, "remission_quantiles": [0.1] * LEVELS}, "40.0 m is not a ground height"),
        ({"ground": -1.7, "remission_quantiles": [0.1] * 3}, f"needs {LEVELS} non-decreasing"),
        ({"ground": -1.7, "remission_quantiles": list(np.linspace(1, 0, LEVELS))}, "non-decreasing"),
    ],
)
def test_a_bad_reference_is_one_line_naming_the_card(data, message):
    with pytest.raises(ConfigError, match=message) as err:
        SensorReference.from_dict(data, "/ck/card.json")
    assert str(err.value).startswith("/ck/card.json: ") and "\n" not in str(err.value)


def _checkpoint(path, reference: SensorReference | None):
    data = {} if reference is None else {"sensor_reference": reference.to_dict()}
    card = ModelCard(architecture={}, class_map=class_map_of(LM), training_data=data, code_version="test")
    return save_checkpoint(path, DSNet(TEST_CONFIG), card)


def test_the_predictor_reads_the_matched_cloud_and_answers_per_given_point(tmp_path):
    ref = _reference(-1.73)
    ck = _checkpoint(tmp_path / "ck", ref)
    low = _street(-0.3, n=6000)
    plain = Predictor.from_checkpoint(ck)
    matched = Predictor.from_checkpoint(ck, match="both")
    got = matched.predict(low)
    want = plain.predict(SensorMatch(ref, "both")(low))
    assert got.sem.shape == (len(low),)
    np.testing.assert_array_equal(got.sem, want.sem)
    np.testing.assert_array_equal(got.offsets, want.offsets)
    assert Predictor.from_checkpoint(ck, match="none").match is None
    bare = _checkpoint(tmp_path / "bare", None)
    with pytest.raises(ConfigError, match="records no sensor reference") as err:
        Predictor.from_checkpoint(bare, match="ground")
    assert str(bare) in str(err.value) and "\n" not in str(err.value)
    with pytest.raises(ConfigError, match="--match 'tilt': choose one of auto, none, ground"):
        Predictor.from_checkpoint(ck, match="tilt")


def test_the_bundled_models_record_their_training_sensor():
    from dsnet_core.checkpoints import DSNET
    from dsnet_core.model.checkpoint import read_card
    from dsnet_core.model.sensor_match import card_reference

    for k in (1, 2):
        path = DSNET.bundled(k)
        ref = card_reference(read_card(path).training_data, str(path))
        assert ref is not None, path
        assert -2.1 < ref.ground < -1.6  # the synthetic stream's sensors sit 1.73–2 m up
        assert 0.15 < ref.remission[50] < 0.3  # the stream's median remission


def test_auto_is_ground_for_a_model_trained_like_a_sensor_and_none_otherwise(tmp_path):
    ref = _reference(-2.1)
    plain = _checkpoint(tmp_path / "plain", ref)  # a reference, but no sensor card: none
    assert Predictor.from_checkpoint(plain).match is None
    assert Predictor.from_checkpoint(_checkpoint(tmp_path / "bare", None)).match is None
    data = {"sensor_reference": ref.to_dict(), "stream": {"sensor_card": {"name": "mine"}}}
    card = ModelCard(architecture={}, class_map=class_map_of(LM), training_data=data, code_version="test")
    like = save_checkpoint(tmp_path / "like", DSNet(TEST_CONFIG), card)
    auto = Predictor.from_checkpoint(like).match
    assert auto == SensorMatch(ref, "ground")
    assert Predictor.from_checkpoint(like, match="none").match is None


def test_infer_config_leaves_the_default_out_of_its_record():
    from tasks.infer import InferConfig

    assert "match" not in InferConfig().model_dump()
    assert "match" in InferConfig(match="none").model_dump()
    assert InferConfig(match="both").model_dump()["match"] == "both"
    with pytest.raises(ValueError, match="match"):
        InferConfig(match="sideways")
