"""The method objects: what each takes from the command line, what it records, its pipeline."""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from tasks.methods import METHODS, LabelSettings, get_method, stage_configs
from tasks.methods.dsnet_train import DsnetTrainOptions


def test_every_method_builds_a_refined_pipeline_by_default_and_a_plain_one_on_request():
    for name, method in METHODS.items():
        refined = method.pipeline()
        assert refined.labels == "refine" and refined.names()[-2:] == ["refine", "score"], name
        assert ("refine", True) in refined.options
        plain = method.pipeline({"refine": False})
        assert "refine" not in plain and plain["score"].upstream[0] == plain.labels, name
        with pytest.raises(ValueError, match=f"method {name} takes no option bogus"):
            method.pipeline({"bogus": 1})


def test_settings_are_validated_once_and_refused_by_flag():
    with pytest.raises(ValidationError, match="scans"):
        LabelSettings(scans=0)
    with pytest.raises(ValidationError, match="expected cpu, cuda or cuda:N"):
        LabelSettings(device="gpu")
    assert stage_configs(scans=1, device="cuda:1")["infer"] == {"device": "cuda:1"}
    with pytest.raises(ValueError, match="--semantic-prior: not a setting of method dsnet"):
        stage_configs(semantic_prior="p")
    assert get_method().options(LabelSettings(refine=False, temporal="track")) == {
        "temporal": "track",
        "refine": False,
    }
    assert get_method("most").options(LabelSettings()) == {}


def test_init_from_bundled_is_the_methods_bundled_model():
    dsnet = get_method()
    opts = DsnetTrainOptions(out="x", init_from="bundled")
    assert opts.start_from(dsnet, 1) == dsnet.bundled_checkpoint(1) is not None
    assert opts.start_from(dsnet, 2) == dsnet.bundled_checkpoint(2)
    assert DsnetTrainOptions(out="x").start_from(dsnet) is None
    for bad, said in (({"batch_size": 0}, "batch_size"), ({"lr": -1}, "lr"), ({"threads": 0}, "threads")):
        with pytest.raises(ValidationError, match=said):
            DsnetTrainOptions(out="x", **bad)


def test_stream_variety_reaches_the_stream():
    from tasks.methods.dsnet_train import stream_reader

    wide = stream_reader(
        DsnetTrainOptions(out="x", stream=3, stream_variety="wide", stream_styles="residential")
    )
    assert wide.options.config.variety == "wide" and wide.record()["variety"] == "wide"
    base = stream_reader(DsnetTrainOptions(out="x", stream=3))
    assert base.options.config.variety == "base" and "variety" not in base.record()
    with pytest.raises(ValidationError, match="stream_variety"):
        DsnetTrainOptions(out="x", stream_variety="narrow")


def test_width_overrides_only_the_presets_base_width():
    from tasks.methods.dsnet_train import model_config

    tiny = model_config(DsnetTrainOptions(out="x"))
    six = model_config(DsnetTrainOptions(out="x", width=6))
    assert (tiny.width, six.width) == (4, 6)
    assert six.point_mlp == tiny.point_mlp and six.grid == tiny.grid
    assert model_config(DsnetTrainOptions(out="x", preset="small")).width == 8
    assert model_config(DsnetTrainOptions(out="x", width=4)) == tiny
    with pytest.raises(ValidationError, match="width"):
        DsnetTrainOptions(out="x", width=0)


def test_a_fine_tune_refuses_another_width_than_its_parents():
    from dsnet_core.errors import ConfigError
    from tasks.methods.dsnet_train import _check_inherited_inputs

    parent = get_method().bundled_checkpoint(1)
    _check_inherited_inputs(DsnetTrainOptions(out="x", width=4), parent)  # the same width: fine
    # the command line passes every option, so an unset --width arrives as an explicit None
    _check_inherited_inputs(DsnetTrainOptions(out="x", width=None), parent)
    with pytest.raises(ConfigError, match=r"--width 6: the --init-from model .* has width 4; a fine-tune"):
        _check_inherited_inputs(DsnetTrainOptions(out="x", width=6), parent)
